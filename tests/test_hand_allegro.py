"""The Allegro hand plugin: registry build, description measured from the model, sim-ready URDF."""

from __future__ import annotations

import importlib.util
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import AssetError, BackendUnavailable
from ges_core.hand import HandModel
from ges_core.kinematics import HandKinematics
from ges_core.registry import load_registry
from ges_core.urdf import absolutize_mesh_paths
from ges_plugins.hands.allegro import hand as allegro

from helpers_sim import pybullet_body

SOURCE = allegro.source_urdf_path()


@pytest.fixture(scope="module")
def hand() -> HandModel:
    return load_registry().build_hand("allegro")


@pytest.fixture(scope="module")
def kin(hand) -> HandKinematics:
    return HandKinematics.from_hand(hand)


def urdf_joints(text: str) -> dict[str, ET.Element]:
    return {j.get("name"): j for j in ET.fromstring(text).findall("joint")}


def chain_to(text: str, link: str) -> tuple[list[str], list[str]]:
    """(links, movable joints) from the root down to ``link``, read straight from the URDF."""
    by_child = {j.find("child").get("link"): j for j in urdf_joints(text).values()}
    links, joints = [link], []
    while link in by_child:
        joint = by_child[link]
        if joint.get("type") != "fixed":
            joints.append(joint.get("name"))
        link = joint.find("parent").get("link")
        links.append(link)
    return links[::-1], joints[::-1]


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def tip_mesh():
    import trimesh

    return trimesh.load(SOURCE.parent / "meshes/collision/link_tip.obj", force="mesh")


# -- building -----------------------------------------------------------------------------
def test_builds_through_the_registry(hand):
    assert isinstance(hand, allegro.AllegroHand)
    assert hand.name == "allegro" and hand.description.base_link == "base_link"


def test_registry_settings_override_the_yaml(write_registry):
    path = write_registry("settings: {hand: {allegro: {scale: 1.5}}}\n")
    assert load_registry(path).build_hand("allegro").description.scale == 1.5


def test_unknown_setting_is_rejected():
    with pytest.raises(AssetError, match=r"invalid description of hand 'allegro': colour: Extra inputs"):
        allegro.build_hand(colour="red")


def test_missing_mani_skill_says_what_to_install(monkeypatch):
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(BackendUnavailable, match=r"mani-skill package \(3.0.1\): pip install 'ges-unigrasp\[allegro\]"):
        allegro.AllegroHand()


def test_missing_urdf_file(monkeypatch):
    monkeypatch.setattr(allegro, "SOURCE_RELPATH", "assets/robots/allegro/nope.urdf")
    with pytest.raises(AssetError, match=r"nope.urdf is missing; reinstall mani-skill==3.0.1"):
        allegro.AllegroHand()


# -- description --------------------------------------------------------------------------
def test_joints_and_limits_come_from_the_urdf(hand):
    d = hand.description
    source = {n: j for n, j in urdf_joints(SOURCE.read_text()).items() if j.get("type") != "fixed"}
    assert d.num_joints == 16 and set(d.joint_names) == set(source)
    for name, (lower, upper) in zip(d.joint_names, d.joint_limits, strict=True):
        limit = source[name].find("limit")
        assert (lower, upper) == (float(limit.get("lower")), float(limit.get("upper")))
    lim = d.limits_array
    assert np.all((lim[:, 0] <= d.open_pose) & (np.asarray(d.open_pose) <= lim[:, 1]))


def test_every_slot_is_served(hand):
    d = hand.description
    physical = [f.slot for f in d.fingers]
    assert sorted(physical) == sorted(set(physical)) == ["index", "middle", "ring", "thumb"]
    assert d.slot_fill == {"little": "ring"}
    assert d.finger_for_slot("little") is d.finger("ring")
    assert [d.finger_for_slot(s).slot for s in FINGER_SLOTS] == ["thumb", "index", "middle", "ring", "ring"]


def test_tip_and_keypoint_links_lie_on_their_finger(hand):
    text = SOURCE.read_text()
    parents = {j.find("parent").get("link") for j in urdf_joints(text).values()}
    for finger in hand.description.fingers:
        links, joints = chain_to(text, finger.tip_link)
        assert joints == list(finger.joints), finger.name
        assert finger.tip_link not in parents, f"{finger.tip_link} has child links"
        assert finger.keypoint_links[-1] == finger.tip_link
        positions = [links.index(k) for k in finger.keypoint_links]
        assert positions == sorted(positions), f"{finger.name} keypoints out of order"


def test_tip_offset_is_the_pad_of_the_tip_surface(hand, kin):
    """On the collision surface, on the side the fingertip moves toward when the distal joint flexes."""
    import trimesh

    d, mesh = hand.description, tip_mesh()
    q = torch.as_tensor([d.open_pose])
    for finger in d.fingers:
        offset = np.asarray(finger.tip_offset)
        _, distance, _ = trimesh.proximity.closest_point(mesh, offset[None])
        assert distance[0] < 1e-4, finger.name
        col = kin.jacobians(q, [finger.tip_link])[0, 0, :, d.joint_index([finger.joints[-1]])[0]].numpy()
        tip_rot = kin.link_poses(q, [finger.tip_link])[0, 0, :3, :3].numpy()
        assert unit(tip_rot.T @ col) @ unit(offset) > 0.999, finger.name


def test_wrist_convention_is_measured(hand, kin):
    """finger_direction: wrist -> middle tip link; palm_normal: where flexing distal joints move the tips."""
    d = hand.description
    q = torch.as_tensor([d.open_pose])
    wrist = kin.link_poses(q, [d.wrist.link])[0, 0].numpy()
    middle = kin.link_poses(q, [d.finger("middle").tip_link])[0, 0, :3, 3].numpy()
    direction = unit(wrist[:3, :3].T @ (middle - wrist[:3, 3]))
    closing = np.zeros(3)
    for finger in (f for f in d.fingers if f.slot != "thumb"):
        distal = d.joint_index([finger.joints[-1]])[0]
        closing += kin.jacobians(q, [finger.tip_link])[0, 0, :, distal].numpy()
    closing = wrist[:3, :3].T @ closing
    normal = unit(closing - (closing @ direction) * direction)
    assert np.degrees(np.arccos(np.clip(direction @ d.wrist.finger_direction, -1, 1))) < 0.1
    assert np.degrees(np.arccos(np.clip(normal @ d.wrist.palm_normal, -1, 1))) < 0.1


def test_middle_finger_length_and_scale_are_measured(hand, kin):
    """l_p: MCP flexion axis (joint_5.0, child link_5.0) to the end of the straight middle fingertip."""
    d = hand.description
    q = torch.as_tensor([d.open_pose])
    tip_link = d.finger("middle").tip_link
    mcp, tip = kin.link_poses(q, ["link_5.0", tip_link])[0].numpy()
    tip_end = tip[:3, 3] + tip[:3, 2] * tip_mesh().bounds[1, 2]  # the cap's far end along the tip's z axis
    assert abs(np.linalg.norm(tip_end - mcp[:3, 3]) - d.middle_finger_length) < 1e-4
    assert d.scale == pytest.approx(d.middle_finger_length / allegro.HUMAN_MIDDLE_FINGER_LENGTH, abs=1e-3)


def test_pd_gains_are_mani_skills(hand):
    spec = importlib.util.find_spec("mani_skill")
    agent = Path(spec.submodule_search_locations[0]) / "agents/robots/allegro_hand/allegro.py"
    text = agent.read_text()
    stiffness = float(re.search(r"self\.joint_stiffness = ([0-9.e+-]+)", text).group(1))
    damping = float(re.search(r"self\.joint_damping = ([0-9.e+-]+)", text).group(1))
    assert set(hand.description.pd_stiffness) == {stiffness}
    assert set(hand.description.pd_damping) == {damping}


# -- the cached URDF ----------------------------------------------------------------------
def test_cached_urdf_is_sim_ready(hand):
    path = hand.urdf_path()
    text = path.read_text()
    root = ET.fromstring(text)
    assert "<material" not in text
    meshes = [m.get("filename") for m in root.iter("mesh")]
    assert meshes and all(Path(m).is_absolute() and Path(m).is_file() for m in meshes)
    assert len(root.findall(".//collision")) == len(ET.fromstring(SOURCE.read_text()).findall(".//collision"))
    assert len(root.findall(".//visual")) > 0  # kept for pictures (PyBullet's CPU renderer)


def test_cached_urdf_is_written_once(hand):
    path = hand.urdf_path()
    stamp = path.stat().st_mtime_ns
    assert allegro.AllegroHand().urdf_path() == path
    assert path.stat().st_mtime_ns == stamp


def test_cached_inertias_are_physical(hand):
    root = ET.fromstring(hand.urdf_path().read_text())
    source_mass = sum(float(m.get("value")) for m in ET.fromstring(SOURCE.read_text()).iter("mass"))
    masses = []
    for link in root.findall("link"):
        inertial = link.find("inertial")
        assert inertial is not None, link.get("name")
        a = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
        tensor = np.array(
            [[a["ixx"], a["ixy"], a["ixz"]], [a["ixy"], a["iyy"], a["iyz"]], [a["ixz"], a["iyz"], a["izz"]]]
        )
        moments = np.linalg.eigvalsh(tensor)
        assert moments[0] > 0 and moments[0] + moments[1] >= moments[2] * (1 - 1e-9), link.get("name")
        masses.append(float(inertial.find("mass").get("value")))
    assert sum(masses) == pytest.approx(source_mass + 2 * allegro.VIRTUAL_MASS)


FIX_URDF = """<robot name="fix">
  <link name="bad_triangle">
    <inertial><mass value="0.1"/><origin xyz="0 0 0" rpy="0.1 0 0"/>
      <inertia ixx="1e-5" iyy="1e-5" izz="3e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.01"/><geometry><box size="0.02 0.04 0.06"/></geometry></collision>
  </link>
  <link name="too_wide">
    <inertial><mass value="0.005"/><inertia ixx="5e-5" iyy="5e-5" izz="6e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><sphere radius="0.01"/></geometry></collision>
  </link>
  <link name="fine">
    <inertial><mass value="0.1"/><inertia ixx="2e-5" iyy="2e-5" izz="3e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><cylinder radius="0.02" length="0.05"/></geometry></collision>
  </link>
  <link name="frame_only"/>
</robot>"""


def test_fix_inertias_replaces_only_impossible_tensors():
    root = ET.fromstring(FIX_URDF)
    assert allegro.fix_inertias(root) == ["bad_triangle", "too_wide"]
    links = {link.get("name"): link for link in root.findall("link")}
    got = {k: float(v) for k, v in links["bad_triangle"].find("inertial/inertia").attrib.items()}
    box = 0.1 / 12 * np.array([0.04**2 + 0.06**2, 0.02**2 + 0.06**2, 0.02**2 + 0.04**2])
    assert [got["ixx"], got["iyy"], got["izz"], got["ixy"]] == pytest.approx([*box, 0.0], rel=1e-6)
    assert links["bad_triangle"].find("inertial/origin").get("rpy") == "0 0 0"
    assert float(links["fine"].find("inertial/inertia").get("izz")) == 3e-5


def test_prepare_urdf_adds_inertials_to_frames():
    text = allegro.prepare_urdf(FIX_URDF, Path("/"))
    frame = ET.fromstring(text).find("link[@name='frame_only']")
    assert float(frame.find("inertial/mass").get("value")) == allegro.VIRTUAL_MASS
    assert "inertia replaced on bad_triangle, too_wide; tiny inertial added to frame_only" in text


@pytest.mark.parametrize(
    ("link", "message"),
    [
        (
            '<link name="l"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="3"/></inertial></link>',
            "link 'l' has an impossible inertia and no collision geometry to fix it",
        ),
        ('<link name="l"><inertial><inertia ixx="1" iyy="1" izz="1"/></inertial></link>', "without <mass>"),
        (
            '<link name="l"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1"/></inertial>'
            '<collision><geometry><capsule radius="1" length="1"/></geometry></collision></link>',
            "unsupported collision geometry <capsule>",
        ),
    ],
)
def test_fix_inertias_errors(link, message):
    with pytest.raises(AssetError, match=re.escape(message)):
        allegro.fix_inertias(ET.fromstring(f"<robot name='x'>{link}</robot>"))


# -- simulators ---------------------------------------------------------------------------
@pytest.mark.sim
def test_pybullet_keeps_every_inertia_of_the_cached_copy(hand):
    """URDF_USE_INERTIA_FROM_FILE zeroes 'bad' tensors: in the source, only ones we replace; in our copy, none."""
    pybullet = pytest.importorskip("pybullet")

    def zeroed(path: Path) -> set[str]:
        client = pybullet.connect(pybullet.DIRECT)
        try:
            flags = pybullet.URDF_USE_INERTIA_FROM_FILE
            body = pybullet.loadURDF(str(path), useFixedBase=True, flags=flags, physicsClientId=client)
            n = pybullet.getNumJoints(body, physicsClientId=client)
            infos = [pybullet.getJointInfo(body, j, physicsClientId=client) for j in range(n)]
            inertias = [pybullet.getDynamicsInfo(body, j, physicsClientId=client)[2] for j in range(n)]
            return {info[12].decode() for info, diag in zip(infos, inertias, strict=True) if min(diag) <= 0}
        finally:
            pybullet.disconnect(client)

    replaced = set(allegro.fix_inertias(ET.fromstring(absolutize_mesh_paths(SOURCE.read_text(), SOURCE.parent))))
    assert zeroed(SOURCE) and zeroed(SOURCE) <= replaced
    assert zeroed(hand.urdf_path()) == set()


@pytest.mark.sim
def test_loads_in_sapien_headless_with_matching_kinematics(hand, kin):
    sapien = pytest.importorskip("sapien")
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])  # CPU recipe: no render device here
    loader = scene.create_urdf_loader()
    loader.fix_root_link = True
    builders, actors, _ = loader.parse(str(hand.urdf_path()))
    assert len(builders) == 1 and not actors
    for link_builder in builders[0].link_builders:
        link_builder.visual_records.clear()
    articulation = builders[0].build(fix_root_link=True)
    joints = [j.name for j in articulation.get_active_joints()]
    assert len(joints) == 16 and set(joints) == set(hand.description.joint_names)
    lim = hand.description.limits_array
    q = np.random.default_rng(0).uniform(lim[:, 0], lim[:, 1])
    articulation.set_qpos(q[hand.description.joint_index(joints)].astype(np.float32))
    links = articulation.get_links()
    ours = kin.link_poses(torch.as_tensor(q[None]), [link.name for link in links])[0, :, :3, 3].numpy()
    theirs = np.array([link.entity_pose.p for link in links])
    assert np.abs(ours - theirs).max() < 1e-3


@pytest.mark.sim
def test_open_pose_has_no_overlapping_links(hand):
    pytest.importorskip("pybullet")
    d = hand.description
    with pybullet_body(hand.urdf_path()) as (pybullet, client, body, infos):
        by_name = {i[1].decode(): i[0] for i in infos}
        for name, value in zip(d.joint_names, d.open_pose, strict=True):
            pybullet.resetJointState(body, by_name[name], value, physicsClientId=client)
        parent = {i[0]: i[16] for i in infos}
        overlaps = []
        for a in range(-1, len(infos)):
            for b in range(a + 1, len(infos)):
                if parent[b] == a:
                    continue
                points = pybullet.getClosestPoints(body, body, 0.0, a, b, physicsClientId=client)
                overlaps += [(a, b, p[8]) for p in points if p[8] < -1e-4]
        assert overlaps == []
