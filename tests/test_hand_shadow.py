"""The Shadow hand plugin: MJCF -> URDF conversion checked against MuJoCo's compiled model.

MuJoCo (``mj_kinematics``) is the ground truth; pytorch-kinematics, PyBullet and SAPIEN read the
converted URDF independently of the converter.
"""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ges_core.errors import AssetError, ConfigError
from ges_core.transforms import quat_to_matrix
from ges_plugins.hands.shadow import assets
from ges_plugins.hands.shadow.convert import (
    collision_meshes_from_mjmodel,
    contact_pairs_from_mjmodel,
    geom_collides,
    subtree_bodies,
    tendon_couplings_from_mjmodel,
    urdf_from_mjmodel,
)
from ges_plugins.hands.shadow.hand import ShadowHand, build_hand

PREFIX = "robot0:"
N_CONFIGS = 20
POS_TOL_M = 1e-4
"""0.1 mm: the brief's tolerance; measured error is ~1e-8 m (pytorch-kinematics parses origins in float32)."""
ROT_TOL_RAD = 1e-4
HUMAN_MIDDLE_FINGER_M = 0.100
"""Human reference MCP-to-tip middle-finger length behind ``scale`` (docs/hands/shadow.md; Allegro uses it too)."""


# -- fixtures and helpers -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def model():
    return assets.compile_model()


@pytest.fixture(scope="module")
def hand() -> ShadowHand:
    return build_hand()


@pytest.fixture(scope="module")
def urdf(hand: ShadowHand) -> ET.Element:
    return ET.fromstring(hand.urdf_text())


@pytest.fixture(scope="module")
def chain(hand: ShadowHand):
    import pytorch_kinematics as pk

    return pk.build_chain_from_urdf(hand.urdf_text().encode()).to(dtype=torch.float64)


def body(model, link: str) -> int:
    return model.body(PREFIX + link).id


def mujoco_link_poses(model, q: np.ndarray, links: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo positions (L, 3) and rotations (L, 3, 3) of ``links`` in the forearm frame for MuJoCo-order ``q``."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    root = body(model, "forearm")
    r0, p0 = data.xmat[root].reshape(3, 3), data.xpos[root]
    ids = [body(model, n) for n in links]
    pos = (data.xpos[ids] - p0) @ r0
    rot = np.einsum("ji,ljk->lik", r0, data.xmat[ids].reshape(-1, 3, 3))
    return pos, rot


def pk_link_poses(chain, model, q: np.ndarray, links: list[str]) -> np.ndarray:
    """(B, L, 4, 4) pytorch-kinematics poses in the base frame for MuJoCo-order ``q`` (B, nq)."""
    order = [model.joint(PREFIX + n).qposadr[0] for n in chain.get_joint_parameter_names()]
    fk = chain.forward_kinematics(torch.as_tensor(q[:, order]))
    return np.stack([fk[n].get_matrix().numpy() for n in links], axis=1)


def random_q(model, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], size=(n, model.nq))


def urdf_links(urdf: ET.Element) -> list[str]:
    return [link.get("name") for link in urdf.findall("link")]


def urdf_inertia(link: ET.Element) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, COM (3,) and inertia tensor (3, 3) of a URDF link (rpy of the inertial origin must be 0)."""
    inertial = link.find("inertial")
    assert inertial.find("origin").get("rpy") == "0.0 0.0 0.0"
    g = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
    tensor = np.array([[g["ixx"], g["ixy"], g["ixz"]], [g["ixy"], g["iyy"], g["iyz"]], [g["ixz"], g["iyz"], g["izz"]]])
    com = np.array(inertial.find("origin").get("xyz").split(), dtype=float)
    return float(inertial.find("mass").get("value")), com, tensor


def copy_assets(dst: Path, *, with_meshes: bool = True) -> Path:
    """A private copy of the hand's MJCF (and STL) files laid out like gymnasium-robotics' assets."""
    src = assets.default_asset_dir()
    shutil.copytree(src / "hand", dst / "hand")
    if with_meshes:
        shutil.copytree(src / assets.MESH_DIR, dst / assets.MESH_DIR)
    return dst


# -- (a) kinematics ------------------------------------------------------------------------------
def test_link_poses_equal_mujoco_for_random_configurations(model, urdf, chain):
    links = urdf_links(urdf)
    assert len(links) == len(subtree_bodies(model, body(model, "forearm"))) == 25
    q = random_q(model, N_CONFIGS)
    got = pk_link_poses(chain, model, q, links)
    for i in range(N_CONFIGS):
        pos, rot = mujoco_link_poses(model, q[i], links)
        pos_err = np.linalg.norm(got[i, :, :3, 3] - pos, axis=-1)
        rot_err = Rotation.from_matrix(np.einsum("lji,ljk->lik", got[i, :, :3, :3], rot)).magnitude()
        assert pos_err.max() < POS_TOL_M, (links[int(pos_err.argmax())], pos_err.max())
        assert rot_err.max() < ROT_TOL_RAD, (links[int(rot_err.argmax())], rot_err.max())


def test_joint_order_names_and_limits_equal_mujoco(model, urdf, hand):
    joints = [j for j in urdf.findall("joint") if j.get("type") != "fixed"]
    mj_names = [model.joint(i).name.removeprefix(PREFIX) for i in range(model.njnt)]
    assert [j.get("name") for j in joints] == mj_names == list(hand.description.joint_names)
    limits = np.array([[float(j.find("limit").get(k)) for k in ("lower", "upper")] for j in joints])
    np.testing.assert_array_equal(limits, model.jnt_range)
    np.testing.assert_array_equal(hand.description.limits_array, model.jnt_range)
    assert all(j.get("type") == "revolute" for j in joints) and model.jnt_limited.all()


def test_armature_is_mujocos_per_joint(model, hand):
    """shadow.yaml's armature is the compiled MJCF's dof_armature, joint by joint (0.005 wrist, 0.001 the rest)."""
    mj = {model.joint(model.dof_jntid[i]).name.removeprefix(PREFIX): model.dof_armature[i] for i in range(model.nv)}
    np.testing.assert_array_equal(hand.description.armature_array, [mj[n] for n in hand.description.joint_names])
    assert set(hand.description.armature) == {0.005, 0.001}


# -- (b), (c) masses and inertias ----------------------------------------------------------------
def test_total_and_link_masses_equal_mujoco(model, urdf):
    masses = {link.get("name"): urdf_inertia(link)[0] for link in urdf.findall("link")}
    assert sum(masses.values()) == pytest.approx(model.body_subtreemass[body(model, "forearm")], rel=1e-12)
    for name, mass in masses.items():
        assert mass == model.body_mass[body(model, name)], name


def test_inertias_positive_definite_and_equal_mujoco_in_world(model, urdf, chain):
    """URDF tensor rotated by pytorch-kinematics FK == MuJoCo's principal inertia rotated by its ``ximat``."""
    links = urdf.findall("link")
    names = [link.get("name") for link in links]
    q = random_q(model, 1, seed=1)
    poses = pk_link_poses(chain, model, q, names)[0]
    data = mujoco.MjData(model)
    data.qpos[:] = q[0]
    mujoco.mj_kinematics(model, data)
    r0 = data.xmat[body(model, "forearm")].reshape(3, 3)
    for link, pose in zip(links, poses, strict=True):
        b = body(model, link.get("name"))
        _, com, tensor = urdf_inertia(link)
        assert np.linalg.eigvalsh(tensor).min() > 0, link.get("name")
        ximat = r0.T @ data.ximat[b].reshape(3, 3)  # MuJoCo's principal axes, forearm frame
        expected = ximat @ np.diag(model.body_inertia[b]) @ ximat.T
        got = pose[:3, :3] @ tensor @ pose[:3, :3].T
        np.testing.assert_allclose(got, expected, atol=1e-6 * model.body_inertia[b].max())  # pk: float32 origins
        np.testing.assert_allclose(com, model.body_ipos[b], atol=1e-12)


# -- collision geometry -------------------------------------------------------------------------
def test_collision_primitives_sit_where_mujoco_puts_its_geoms(model, urdf, chain):
    """Each URDF collision's centre and axis (FK) equal the colliding MuJoCo geom's (``geom_xpos/xmat``)."""
    q = random_q(model, 1, seed=2)
    data = mujoco.MjData(model)
    data.qpos[:] = q[0]
    mujoco.mj_kinematics(model, data)
    r0, p0 = data.xmat[body(model, "forearm")].reshape(3, 3), data.xpos[body(model, "forearm")]
    names = urdf_links(urdf)
    poses = dict(zip(names, pk_link_poses(chain, model, q, names)[0], strict=True))
    for link in urdf.findall("link"):
        b = body(model, link.get("name"))
        geoms = [g for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b])]
        geoms = [g for g in geoms if geom_collides(model, g)]
        assert len(link.findall("collision")) == len(geoms), link.get("name")
        for col, g in zip(link.findall("collision"), geoms, strict=True):
            origin = col.find("origin")
            local = np.eye(4)
            local[:3, :3] = Rotation.from_euler("xyz", np.array(origin.get("rpy").split(), dtype=float)).as_matrix()
            local[:3, 3] = np.array(origin.get("xyz").split(), dtype=float)
            world = poses[link.get("name")] @ local
            np.testing.assert_allclose(world[:3, 3], (data.geom_xpos[g] - p0) @ r0, atol=POS_TOL_M)
            np.testing.assert_allclose(world[:3, :3], r0.T @ data.geom_xmat[g].reshape(3, 3), atol=ROT_TOL_RAD)


def test_capsule_and_box_sizes_equal_mujoco(model, urdf):
    sizes = {"capsule": [], "box": []}
    for tag in sizes:
        for geom in urdf.iter(tag):
            attrs = geom.attrib
            sizes[tag].append(
                [float(attrs["radius"]), float(attrs["length"]) / 2]
                if tag == "capsule"
                else list(np.array(attrs["size"].split(), dtype=float) / 2)
            )
    colliding = [g for g in range(model.ngeom) if geom_collides(model, g)]
    for tag, kind, dims in (("capsule", mujoco.mjtGeom.mjGEOM_CAPSULE, 2), ("box", mujoco.mjtGeom.mjGEOM_BOX, 3)):
        expected = [model.geom_size[g][:dims].tolist() for g in colliding if model.geom_type[g] == kind]
        np.testing.assert_allclose(sizes[tag], expected)


def test_forearm_mesh_matches_the_stl_placed_as_the_mjcf_says(hand, urdf):
    """Independent of MuJoCo's mesh re-centring: raw STL at robot.xml's pos/euler == OBJ at the URDF origin."""
    import trimesh

    stl = trimesh.load(assets.default_asset_dir() / assets.MESH_DIR / "forearm_electric_cvx.stl")
    geom = ET.parse(assets.default_asset_dir() / "hand" / "robot.xml").find(".//geom[@name='robot0:C_forearm']")
    mjcf_rot = Rotation.from_euler("XYZ", np.array(geom.get("euler").split(), dtype=float)).as_matrix()
    expected = stl.vertices @ mjcf_rot.T + np.array(geom.get("pos").split(), dtype=float)
    col = [c for c in urdf.find("link[@name='forearm']").findall("collision")][0]
    obj = trimesh.load(col.find("geometry/mesh").get("filename"), process=False)
    origin = col.find("origin")
    rot = Rotation.from_euler("xyz", np.array(origin.get("rpy").split(), dtype=float)).as_matrix()
    got = obj.vertices @ rot.T + np.array(origin.get("xyz").split(), dtype=float)
    assert cKDTree(got).query(expected)[0].max() < 1e-6
    assert cKDTree(expected).query(got)[0].max() < 1e-6


def test_contact_pairs_name_links_with_collision_geometry(model, urdf):
    with_collision = {link.get("name") for link in urdf.findall("link") if link.find("collision") is not None}
    pairs = contact_pairs_from_mjmodel(model)
    assert len(pairs) == len(set(pairs)) > 0
    assert {n for pair in pairs for n in pair} <= with_collision


# -- tendon coupling ----------------------------------------------------------------------------
def test_declared_couplings_are_mujocos_tendons(model, hand):
    derived = {(c.follower, c.leader): c.ratio for c in tendon_couplings_from_mjmodel(model)}
    declared = {(c.follower, c.leader): c.ratio for c in hand.description.couplings}
    assert declared.keys() == derived.keys()
    for key, ratio in declared.items():
        assert ratio == pytest.approx(derived[key], abs=1e-6), key


def test_mujoco_keeps_the_follower_within_the_tendon_band(model):
    """Drive FFJ1 with MuJoCo's own actuator: FFJ0 stays within ratio * FFJ1 +- slack (our reading of the tendon)."""
    coupling = next(c for c in tendon_couplings_from_mjmodel(model) if c.follower == "FFJ0")
    data = mujoco.MjData(model)
    j1, j0 = model.joint(PREFIX + "FFJ1").qposadr[0], model.joint(PREFIX + "FFJ0").qposadr[0]
    for target in (0.3, 0.9, 1.3):
        data.ctrl[model.actuator(PREFIX + "A_FFJ1").id] = target
        for _ in range(500):
            mujoco.mj_step(model, data)
        assert abs(data.qpos[j1] - target) < 0.05
        assert abs(data.qpos[j0] - coupling.ratio * data.qpos[j1]) <= coupling.slack + 0.01


# -- description measured from the model --------------------------------------------------------
def test_wrist_convention_tip_offsets_and_sizes_are_measured_values(model, hand, chain):
    d = hand.description
    q = np.zeros((1, model.nq))
    q[0, d.joint_index(list(d.joint_names))] = d.open_pose
    links = ["palm", "mfknuckle", "mfproximal", "mfdistal"]
    poses = dict(zip(links, pk_link_poses(chain, model, q, links)[0], strict=True))
    palm_inv = np.linalg.inv(poses["palm"])
    mf = d.finger("mf")
    tip = (palm_inv @ poses["mfdistal"] @ np.append(mf.tip_offset, 1))[:3]
    direction = tip / np.linalg.norm(tip)
    np.testing.assert_allclose(d.wrist.finger_direction, direction, atol=1e-4)
    axis = (palm_inv @ poses["mfproximal"])[:3, :3] @ model.jnt_axis[model.joint(PREFIX + "MFJ2").id]
    normal = np.cross(axis, direction)
    np.testing.assert_allclose(d.wrist.palm_normal, normal / np.linalg.norm(normal), atol=1e-4)
    capsule = model.geom(PREFIX + "C_mfdistal")
    tip_end = poses["mfdistal"] @ np.append([0, 0, capsule.pos[2] + capsule.size[1] + capsule.size[0]], 1)
    length = np.linalg.norm(tip_end[:3] - poses["mfknuckle"][:3, 3])
    assert d.middle_finger_length == pytest.approx(length, abs=1e-5)
    assert d.scale == pytest.approx(length / HUMAN_MIDDLE_FINGER_M, abs=1e-4)


@pytest.mark.parametrize("finger", ["th", "ff", "mf", "rf", "lf"])
def test_tip_offset_is_on_the_distal_capsule_surface_on_the_flexing_side(model, hand, finger):
    spec = hand.description.finger(finger)
    capsule = model.geom(PREFIX + "C_" + spec.tip_link)
    point = np.asarray(spec.tip_offset)
    axis_point = capsule.pos + np.array([0, 0, np.clip(point[2] - capsule.pos[2], -capsule.size[1], capsule.size[1])])
    assert np.linalg.norm(point - axis_point) == pytest.approx(capsule.size[0], abs=1e-6)
    jnt = model.joint(PREFIX + spec.joints[-1]).id
    closing = np.sign(model.jnt_range[jnt].sum()) * np.cross(model.jnt_axis[jnt], point)  # flexion direction
    assert closing @ (point - axis_point) > 0


def test_hand_passes_lint_except_knuckle_collision(hand):
    """``collision`` is skipped: the four zero-length knuckle links have no geometry in the MJCF either."""
    from ges_core.lint import lint_hand

    assert lint_hand(hand, skip=("collision",)) == []


def test_registry_builds_the_shadow_hand():
    from ges_core.registry import load_registry

    built = load_registry().build_hand("shadow")
    assert isinstance(built, ShadowHand) and built.description.num_joints == 24
    assert built.description.base_link == "forearm"


def test_settings_override_yaml_keys():
    assert build_hand(scale=1.25).description.scale == 1.25
    with pytest.raises(AssetError, match="colour"):
        build_hand(colour="red")


# -- (e) cache ----------------------------------------------------------------------------------
def test_cache_is_reused_and_keyed_by_source_content(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    first = assets.cached_urdf()
    stamp = first.stat().st_mtime_ns
    assert assets.cached_urdf() == first and first.stat().st_mtime_ns == stamp
    copy = copy_assets(tmp_path / "assets")
    assert assets.cached_urdf(copy) == first  # same bytes elsewhere: same key
    robot = copy / "hand" / "robot.xml"
    robot.write_text(robot.read_text().replace('range="-0.489 0.14"', 'range="-0.489 0.10"'))
    changed = assets.cached_urdf(copy)
    assert changed != first and first.stat().st_mtime_ns == stamp
    assert 'upper="0.1"' in changed.read_text() and 'upper="0.1"' not in first.read_text()


# -- (f) errors ---------------------------------------------------------------------------------
def test_missing_asset_names_the_file_and_the_package(tmp_path):
    with pytest.raises(AssetError, match=r"hand/robot\.xml is missing.*pip install 'ges-unigrasp\[shadow\]'"):
        build_hand(asset_dir=tmp_path)


def test_missing_mesh_names_the_stl(tmp_path):
    copy = copy_assets(tmp_path, with_meshes=False)
    with pytest.raises(AssetError, match=r"stls/hand/forearm_electric\.stl is missing.*'ges-unigrasp\[shadow\]'"):
        assets.cached_urdf(copy)


def test_missing_package_says_how_to_install(monkeypatch):
    monkeypatch.setattr(assets.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(AssetError, match=r"gymnasium-robotics, which is not installed: pip install 'ges-unigrasp\["):
        assets.default_asset_dir()


def test_invalid_asset_xml_is_reported(tmp_path):
    copy = copy_assets(tmp_path)
    (copy / "hand" / "shared_asset.xml").write_text("<mujoco><mesh")
    with pytest.raises(AssetError, match="shared_asset.xml is not valid XML"):
        assets.cached_urdf(copy)


def test_compile_failure_is_reported(tmp_path):
    copy = copy_assets(tmp_path)
    robot = copy / "hand" / "robot.xml"
    robot.write_text(robot.read_text().replace('mesh="robot0:forearm_cvx"', 'mesh="robot0:nothing"'))
    with pytest.raises(AssetError, match="MuJoCo cannot compile the Shadow hand"):
        assets.cached_urdf(copy)


CONVERTER_ERRORS = {
    "ball joint": ('<joint type="ball"/><geom size="0.01"/>', "only hinge and slide"),
    "two joints": ('<joint axis="1 0 0"/><joint axis="0 1 0"/><geom size="0.01"/>', "has 2 joints"),
    "joint off origin": ('<joint pos="0 0 0.1" axis="1 0 0"/><geom size="0.01"/>', "not at the body origin"),
    "ellipsoid": ('<joint axis="1 0 0"/><geom type="ellipsoid" size="0.01 0.02 0.03"/>', "no URDF equivalent"),
}


@pytest.mark.parametrize("case", sorted(CONVERTER_ERRORS))
def test_converter_rejects_what_urdf_cannot_hold(case):
    child, message = CONVERTER_ERRORS[case]
    xml = (
        '<mujoco><worldbody><body name="base"><geom size="0.01"/>'
        f'<body name="b" pos="0 0 0.1">{child}</body></body></worldbody></mujoco>'
    )
    with pytest.raises(AssetError, match=message):
        urdf_from_mjmodel(mujoco.MjModel.from_xml_string(xml), root_body="base")


def test_converter_names_known_bodies_for_an_unknown_root(model):
    with pytest.raises(AssetError, match="no body 'hand'.*robot0:forearm"):
        urdf_from_mjmodel(model, root_body="hand")


def test_meshes_only_for_colliding_mesh_geoms(model):
    assert list(collision_meshes_from_mjmodel(model)) == ["forearm_cvx.obj"]


# -- (g) simulators -----------------------------------------------------------------------------
@pytest.mark.sim
def test_pybullet_loads_24_joints_capsules_and_masses(hand, model):
    import pybullet as p

    client = p.connect(p.DIRECT)
    try:
        uid = p.loadURDF(str(hand.urdf_path()), flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        infos = [
            p.getJointInfo(uid, i, physicsClientId=client) for i in range(p.getNumJoints(uid, physicsClientId=client))
        ]
        assert [i[1].decode() for i in infos if i[2] == p.JOINT_REVOLUTE] == list(hand.description.joint_names)
        masses = [p.getDynamicsInfo(uid, i, physicsClientId=client)[0] for i in range(-1, len(infos))]
        assert sum(masses) == pytest.approx(model.body_subtreemass[body(model, "forearm")])
        shapes = p.getCollisionShapeData(uid, [i[12].decode() for i in infos].index("ffdistal"), physicsClientId=client)
        assert [(s[2], s[3][:2]) for s in shapes] == [(p.GEOM_CAPSULE, pytest.approx((0.024, 0.00705)))]
    finally:
        p.disconnect(client)


@pytest.mark.sim
def test_sapien_loads_24_joints_and_places_links_like_mujoco(hand, model):
    import sapien

    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    loader = scene.create_urdf_loader()
    loader.fix_root_link = True
    builders = loader.parse(str(hand.urdf_path()))[0]
    assert len(builders) == 1
    for link_builder in builders[0].link_builders:
        link_builder.visual_records = []
    art = builders[0].build()
    names = [j.name for j in art.get_active_joints()]
    assert sorted(names) == sorted(hand.description.joint_names)
    q = random_q(model, 1, seed=3)[0]
    art.set_qpos(np.array([q[model.joint(PREFIX + n).qposadr[0]] for n in names]))
    links = art.get_links()
    pos, _ = mujoco_link_poses(model, q, [link.name for link in links])
    got = np.array([link.entity_pose.p for link in links])
    assert np.abs(got - pos).max() < POS_TOL_M
    capsules = [s for s in art.find_link_by_name("ffdistal").get_collision_shapes()]
    assert type(capsules[0]).__name__ == "PhysxCollisionShapeCapsule"
    axis = quat_to_matrix(capsules[0].get_local_pose().q)[:, 0]  # PhysX capsules lie along their x axis
    np.testing.assert_allclose(np.abs(axis), [0, 0, 1], atol=1e-6)


def test_unknown_self_collision_setting_is_a_config_error_naming_the_choices():
    with pytest.raises(ConfigError, match=r"self_collision 'some' is not one of mjcf_pairs, all"):
        ShadowHand(self_collision="some")


def test_a_self_collision_exclude_override_replaces_the_mjcf_pairs(hand):
    """The default leaves out every pair the MJCF does not list; a user's own list wins over it."""
    assert len(hand.description.self_collision_exclude) == 170
    own = ShadowHand(self_collision_exclude=[["ffdistal", "palm"]])
    assert own.description.self_collision_exclude == (("ffdistal", "palm"),)


# -- armature in the engines (docs/hands/shadow.md, "Armature") ------------------------------------
def test_sapien_gives_each_hand_joint_the_declared_armature(hand):
    from ges_core.registry import load_registry
    from ges_core.sim import SceneConfig

    with load_registry().build_sim("sapien", SceneConfig()) as sim:
        sim.load_hand(hand, floating=True)
        joints = {j.name: float(np.asarray(j.armature).ravel()[0]) for j in sim._envs[0].hand.get_active_joints()}
    want = dict(zip(hand.description.joint_names, hand.description.armature, strict=True))
    assert {n: joints[n] for n in want} == pytest.approx(want, rel=1e-6)  # float32 in PhysX
    assert all(joints[n] == 0.0 for n in joints if n not in want)  # the floating wrist's virtual joints: none


def test_with_the_mjcf_armature_a_blocked_fingertip_presses_the_squeeze_in_both_engines(hand):
    """The lint's probe (each finger closes on a fixed cube under validation's squeeze; 5 N asked per tip), against
    the PD law it asks for. Without the armature SAPIEN's light distal links chatter against the cube and every tip
    presses under 3 N (measured 1.1-2.3 N); with it every tip presses at least 3.5 N (measured 4.5-6.8 N). PyBullet
    leaves the armature out and keeps at least the lint's half (measured 3.4-6.4 N)."""
    from ges_core.lint.checks_probe import PROBE_SHARE, probe_tip_forces
    from ges_core.registry import load_registry

    registry = load_registry()
    with_armature, asked = probe_tip_forces(hand, registry.build_sim, "sapien")
    without, _ = probe_tip_forces(build_hand(armature=None), registry.build_sim, "sapien")
    bullet, _ = probe_tip_forces(hand, registry.build_sim, "pybullet")
    assert asked == 5.0
    assert with_armature.min() >= 0.7 * asked, with_armature
    assert without.max() < 0.6 * asked, without  # the control: the armature is what made the difference
    assert bullet.min() >= PROBE_SHARE * asked, bullet


def test_with_the_mjcf_armature_a_blocked_finger_is_still_in_sapien(hand):
    """One finger closing at a time (``probe_fingers(alone=True)``: no neighbour presses on its cube): with the
    armature every tip presses at least 3 N of 5 N and no joint moves faster than 0.1 rad/s after the squeeze
    (measured 3.6-6.1 N, 0.02 rad/s); without it the blocked finger chatters (measured 0.26 rad/s)."""
    from ges_core.lint.checks_probe import probe_fingers
    from ges_core.registry import load_registry

    registry = load_registry()
    still = probe_fingers(hand, registry.build_sim, "sapien", alone=True)
    chatter = probe_fingers(build_hand(armature=None), registry.build_sim, "sapien", alone=True)
    assert still.forces.min() >= 3.0 and still.joint_speed < 0.1, still
    assert chatter.joint_speed > 0.1, chatter


def test_a_thumb_asked_for_twice_the_squeeze_presses_harder_and_no_other_finger_changes(hand):
    """The Shadow's thumb asks for up to twice the squeeze on a heavy object (``settings.validate.thumb_force_per_kg``,
    ``ValidateConfig.thumb_force``). Through the probe, one finger closing at a time, in both engines: asked for 10 N
    instead of 5 N, the thumb's tip presses at least 1.4 times harder (measured 4.7 -> 7.4 N in SAPIEN, 4.9 -> 8.5 N
    in PyBullet), and every other finger presses exactly what it did (its targets and scene are the same)."""
    from ges_core.lint.checks_probe import probe_fingers
    from ges_core.registry import load_registry

    registry = load_registry()
    d = hand.description
    thumb = [f.name for f in d.fingers].index(d.finger_for_slot("thumb").name)
    for sim in ("sapien", "pybullet"):
        plain = probe_fingers(hand, registry.build_sim, sim, alone=True)
        harder = probe_fingers(hand, registry.build_sim, sim, alone=True, thumb_force=10.0)
        assert harder.forces[thumb] >= 1.4 * plain.forces[thumb], (sim, plain, harder)
        np.testing.assert_array_equal(np.delete(harder.forces, thumb), np.delete(plain.forces, thumb), err_msg=sim)
