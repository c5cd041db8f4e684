"""The retracted hand kept above the table (``ges_core.synthesis.physics.table_clearance``): which finger moves which
link (against the URDF's own tree), the points' heights (against the simulators' link poses), the capped
retraction (every finger clears, none is shortened more than it must be) and a real engine's table contact."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ges_core.kinematics import shared_kinematics
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import grasp_start_pose
from ges_core.synthesis.physics.pregrasp import PregraspConfig, pregrasp
from ges_core.synthesis.physics.refine import RefineConfig
from ges_core.synthesis.physics.scene import hand_contacts, stage_scene
from ges_core.synthesis.physics.squeeze import retract_joints
from ges_core.synthesis.physics.table_clearance import finger_points, table_clear_retract
from ges_core.synthesis.types import Grasp
from ges_core.transforms import matrix_to_pose, pose_to_matrix, quat_to_matrix
from ges_core.urdf import parse_urdf

REGISTRY = load_registry(autoload=False)
HANDS = tuple(REGISTRY.names("hand"))
SIMS = tuple(REGISTRY.names("sim"))
CLEARANCE = RefineConfig().start_clearance
TRAVEL = RefineConfig().start_retract


@pytest.fixture(scope="module", params=HANDS)
def hand(request):
    return REGISTRY.build_hand(request.param)


def _ancestor_joints(urdf_text: str) -> dict[str, set[str]]:
    """Every link's movable ancestor joints, read from the URDF's <joint> parent/child tags."""
    root = parse_urdf(urdf_text)
    parent = {
        j.find("child").get("link"): (j.get("name"), j.get("type"), j.find("parent").get("link"))
        for j in root.iter("joint")
    }
    out = {}
    for link in (e.get("name") for e in root.iter("link")):
        joints, at = set(), link
        while at in parent:
            name, kind, at = parent[at]
            if kind != "fixed":
                joints.add(name)
        out[link] = joints
    return out


def _low_grasp(hand):
    """A grasp whose full retraction takes some finger below the clearance while its own collision points stay
    10 mm above the table: the palm-down grasp of ``closed_pose(0.5)`` tilted 60 degrees about world y (the
    fingers' press directions then point down), lowered to that height. (base pose (7,), q (K,), (2, F) lowest
    point per finger at the grasp and at the full retraction, m)."""
    d, pts, kin = hand.description, finger_points(hand), shared_kinematics(hand)
    q = d.apply_couplings(d.closed_pose(0.5))
    full = retract_joints(hand, q, travel=TRAVEL)
    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("y", 60.0, degrees=True).as_matrix()
    base = tilt @ pose_to_matrix(grasp_start_pose(hand, np.array([0.0, 0.0, 0.1]), 0.5))
    z = pts.heights(kin, q[None], base)[0]
    base[2, 3] += 0.010 - z.min()
    z = pts.heights(kin, np.stack([q, full]), base)
    low = np.array([[z[k, pts.finger_of == f].min() for f in range(len(d.fingers))] for k in range(2)])
    assert low[0].min() > CLEARANCE > low[1].min(), low  # the case this helper is for
    return matrix_to_pose(base), q, low


def test_each_link_belongs_to_the_finger_whose_joints_move_it(hand):
    """Membership from forward kinematics under a probe against the URDF's tree: a link is finger f's when one of
    f's joints is among its ancestors, the palm's (-1) when none is."""
    d, pts = hand.description, finger_points(hand)
    ancestors = _ancestor_joints(hand.urdf_text())
    assert len(pts.links) > len(d.fingers)
    for i, link in enumerate(pts.links):
        owners = [f for f, finger in enumerate(d.fingers) if ancestors[link] & set(finger.joints)]
        expected = owners[0] if owners else -1
        assert len(owners) <= 1, (link, owners)
        assert set(pts.finger_of[pts.link_of == i]) == {expected}, link
    assert set(range(len(d.fingers))) <= set(pts.finger_of.tolist())  # every finger has collision points


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_point_heights_match_the_simulators_link_poses(hand, sim_name):
    """The heights from pytorch-kinematics against the same points carried by the engine's own link poses."""
    d, pts = hand.description, finger_points(hand)
    q = d.apply_couplings(d.closed_pose(0.4))
    base = grasp_start_pose(hand, np.array([0.01, -0.02, 0.3]), 0.4)
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        sim.load_hand(hand)
        sim.set_hand_state(q[None], base[None])
        poses = sim.link_poses(list(pts.links))[0]  # (L, 7), world
    rot = quat_to_matrix(poses[:, 3:])[pts.link_of]
    engine = np.einsum("nij,nj->ni", rot, pts.points)[:, 2] + poses[pts.link_of, 2]
    ours = pts.heights(shared_kinematics(hand), q[None], pose_to_matrix(base))[0]
    np.testing.assert_allclose(ours, engine, atol=1e-5)


def test_capped_retraction_keeps_every_finger_above_the_table_and_no_lower_than_needed(hand):
    d, pts, kin = hand.description, finger_points(hand), shared_kinematics(hand)
    base, q, low = _low_grasp(hand)
    out, kept = table_clear_retract(hand, q, base, travel=TRAVEL, clearance=CLEARANCE)
    z = pts.heights(kin, out[None], pose_to_matrix(base))[0]
    full = retract_joints(hand, q, travel=TRAVEL)
    for f, finger in enumerate(d.fingers):
        mine, idx = pts.finger_of == f, d.joint_index(finger.joints)
        assert z[mine].min() >= CLEARANCE, finger.name  # the grasp itself is above it (_low_grasp)
        if low[1, f] >= CLEARANCE:  # clear at the full travel: untouched
            assert kept[f] == 1.0, finger.name
            np.testing.assert_allclose(out[idx], full[idx], atol=1e-12, err_msg=finger.name)
        else:  # shortened, and the next longer fraction tried would not clear
            assert kept[f] < 1.0, finger.name
            longer = np.ones(len(d.fingers))
            longer[f] = kept[f] + 0.25
            q_longer = retract_joints(hand, q, travel=TRAVEL, finger_scale=longer)
            assert pts.heights(kin, q_longer[None], pose_to_matrix(base))[0][mine].min() < CLEARANCE, finger.name
    assert (kept < 1.0).any()


def test_a_hand_high_above_the_table_keeps_the_full_retraction(hand):
    d = hand.description
    q = d.apply_couplings(d.closed_pose(0.5))
    base = grasp_start_pose(hand, np.array([0.0, 0.0, 0.3]), 0.5)
    out, kept = table_clear_retract(hand, q, base, travel=TRAVEL, clearance=CLEARANCE)
    assert (kept == 1.0).all()
    np.testing.assert_array_equal(out, retract_joints(hand, q, travel=TRAVEL))
    with pytest.raises(ValueError, match="fractions must be at least 1"):
        table_clear_retract(hand, q, base, travel=TRAVEL, clearance=CLEARANCE, fractions=0)


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_the_engine_finds_the_capped_hand_off_the_table(hand, sim_name):
    """In the engine's own collision geometry: the fully retracted hand of the low grasp touches the table, the
    capped one does not (the hand set there and held one step, the object far away)."""
    base, q, _ = _low_grasp(hand)
    full = retract_joints(hand, q, travel=TRAVEL)
    capped, _ = table_clear_retract(hand, q, base, travel=TRAVEL, clearance=CLEARANCE)
    away = box_asset((0.02, 0.02, 0.02), density=300.0, object_id="test/away_box")
    touches = {}
    for name, q_start in (("full", full), ("capped", capped)):
        with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
            stage_scene(sim, hand, away)
            sim.set_object_pose(np.array([[0.5, 0.5, 0.02, 1.0, 0.0, 0.0, 0.0]]))
            sim.set_hand_state(q_start[None], base[None])
            sim.set_joint_targets(q_start[None])
            sim.set_wrist_targets(base[None])
            sim.step(1)
            touches[name] = hand_contacts(sim, RefineConfig().table_force).table
    assert touches == {"full": True, "capped": False}, touches


def test_the_pregrasp_clears_the_table_at_both_ends_of_its_approach(hand):
    """The pre-grasp's opened hand is the capped retraction over the grasp pose and the backed-off pose: each finger
    clears the table at both, and the lower pose decides (the grasp's when the approach comes down, the backed-off
    one, 20 mm lower, when it comes up)."""
    d, pts, kin = hand.description, finger_points(hand), shared_kinematics(hand)
    base, q, _ = _low_grasp(hand)
    grasp = Grasp(hand=hand.name, wrist_pose=base, q=q)
    config = PregraspConfig()
    for approach in (np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])):
        pre = pregrasp(hand, grasp, approach)
        both = np.stack([base, pre.wrist_pose])
        expected, _ = table_clear_retract(hand, q, both, travel=config.retract, clearance=config.clearance)
        np.testing.assert_array_equal(pre.q, expected)
        for pose in both:
            at_grasp = pts.heights(kin, q[None], pose_to_matrix(pose))[0]
            z = pts.heights(kin, pre.q[None], pose_to_matrix(pose))[0]
            for f in range(len(d.fingers)):
                mine = pts.finger_of == f
                assert z[mine].min() >= min(config.clearance, at_grasp[mine].min()) - 1e-12, (approach, f)
    for approach, lower in ((np.array([0.0, 0.0, -1.0]), base), (np.array([0.0, 0.0, 1.0]), None)):
        pre = pregrasp(hand, grasp, approach)
        lower = pre.wrist_pose if lower is None else lower  # one rotation: the lower pose is the lower everywhere
        alone, _ = table_clear_retract(hand, q, lower, travel=config.retract, clearance=config.clearance)
        np.testing.assert_array_equal(pre.q, alone)
    full = pregrasp(hand, grasp, np.array([0.0, 0.0, -1.0]), PregraspConfig(clearance=None)).q
    np.testing.assert_array_equal(full, retract_joints(hand, q, travel=config.retract))


def test_a_dataset_written_before_the_cap_reads_and_resumes_as_the_full_retraction():
    """Its stored run config lacks both keys: read back, they are null (the full retraction it ran with, not the new
    5 mm), and a run asking for null stores exactly what it stored, so it resumes; the default stores 5 mm, so a
    default run is refused on resume rather than mixed."""
    from ges_core.synthesis import SynthesisConfig

    full = SynthesisConfig.model_validate({"refine": {"start_clearance": None}, "pregrasp": {"clearance": None}})
    old = full.dump()
    assert "start_clearance" not in old["refine"] and "clearance" not in old["pregrasp"]
    new = SynthesisConfig().dump()
    assert (new["refine"]["start_clearance"], new["pregrasp"]["clearance"]) == (CLEARANCE, CLEARANCE)
    written = SimpleNamespace(run_config=old, manifest={"version": 3}, root="old-dataset")  # what of_dataset reads
    read = SynthesisConfig.of_dataset(written)
    assert read.refine.start_clearance is None and read.pregrasp.clearance is None
    assert read == full
