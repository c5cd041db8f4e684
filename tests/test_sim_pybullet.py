"""The PyBullet backend against independent references: PyBullet's own joint and body API, trimesh
volumes, gravity and the physics of a resting box and a squeezed one. What every backend must do
(FK against pytorch-kinematics, rest heights, joint and wrist driving, object replacement, reset,
determinism, argument and state errors) is in test_sim_contract.py."""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import numpy as np
import pybullet as p
import pytest

from ges_core.errors import AssetError, ConfigError, SimulationError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.transforms import quat_to_matrix
from ges_core.urdf import WRIST_JOINTS
from ges_plugins.sims.pybullet import shapes
from ges_plugins.sims.pybullet.backend import MAX_JOINT_SPEED, PybulletBackend
from ges_plugins.sims.pybullet.bench import grasp_scene
from ges_plugins.sims.pybullet.drive import ImplicitPD, product_friction
from ges_plugins.sims.pybullet.hand_urdf import principal_moments, pybullet_hand_urdf, sanitize_inertias

from helpers_sim import UP, TestHand, allegro_test_hand, box_asset, loaded_sim, open_q, reordered, run_python

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def hand():
    return allegro_test_hand()


make_sim = partial(loaded_sim, PybulletBackend)
"""A PybulletBackend with ``SceneConfig(**scene)``, the hand loaded if given."""


def single_shape(shape, density: float = 500.0) -> ObjectAsset:
    return ObjectAsset(
        object_id="t/shape", category="t", mesh_path=box_asset().mesh_path, collision=(shape,), density=density
    )


# -- setting, output and joint order ----------------------------------------------------------------
def test_solver_iterations_setting_overrides_the_scene_config():
    """registry.yaml ``settings.sim.pybullet.solver_iterations`` reaches PyBullet; SceneConfig's value otherwise."""
    override = ("settings.sim.pybullet.solver_iterations=100",)
    registry = load_registry(overrides=override, blocked=("shadow", "allegro", "sapien"))
    for sim, expected in ((registry.build_sim("pybullet", SceneConfig(num_envs=2)), 100), (make_sim(), 20)):
        with sim:
            used = {p.getPhysicsEngineParameters(physicsClientId=s.cid)["numSolverIterations"] for s in sim._scenes}
            assert used == {expected} and sim.solver_iterations == expected
    for bad in (0, 2.5, True):
        with pytest.raises(ConfigError, match=rf"pybullet: solver_iterations={bad!r}; give a whole number >= 1"):
            PybulletBackend(SceneConfig(), solver_iterations=bad)


def test_pybullet_chatter_stays_out_of_ges_output():
    """PyBullet prints 'pybullet build time' (stderr) on import and 'argv[0]=' (stdout) per client;
    ``ges sim check`` shows neither."""
    raw = run_python("-c", "from pybullet_utils.bullet_client import BulletClient as C; C(connection_mode=2)")
    assert "argv[0]=" in raw.stdout and "pybullet build time" in raw.stderr  # the control: the chatter exists
    args = ("--hand", "allegro", "--sim", "pybullet", "-o", "close_steps=5", "-o", "lift_steps=0")
    ges = run_python("-m", "ges_core.cli", "sim", "check", *args)
    assert "hand allegro in pybullet:" in ges.stdout, ges.stderr  # the check ran and printed its report
    for line in (ges.stdout + ges.stderr).splitlines():
        assert "argv[0]" not in line and "build time" not in line


def test_silenced_hides_c_and_python_output_of_the_block_only():
    code = """
import ctypes, os, sys
from ges_plugins.sims.pybullet.engine import silenced
libc = ctypes.CDLL(None)
print("before", flush=False)
with silenced(1, 2):
    libc.printf(b"hidden-c\\n"); print("hidden-py"); print("hidden-err", file=sys.stderr); os.write(2, b"hidden-fd\\n")
libc.printf(b"after-c\\n"); print("after-py"); print("after-err", file=sys.stderr)
"""
    out = run_python("-c", code)
    assert sorted(out.stdout.split()) == ["after-c", "after-py", "before"] and out.stderr.split() == ["after-err"]


@pytest.mark.parametrize("floating", [True, False])
def test_joint_order_is_mapped_by_name(hand, floating):
    """A hand declaring its joints in reverse order: every value lands on the PyBullet joint of that name."""
    flipped = reordered(hand, list(range(hand.description.num_joints))[::-1])
    d = flipped.description
    lim = d.limits_array
    q = lim[:, 0] + (np.arange(d.num_joints) + 1) / (d.num_joints + 1) * (lim[:, 1] - lim[:, 0])
    sim = make_sim(flipped, floating=floating)
    sim.set_hand_state(q[None], UP[None])
    scene = sim._scenes[0]
    by_name = {}
    for j in range(p.getNumJoints(scene.hand, physicsClientId=scene.cid)):
        info = p.getJointInfo(scene.hand, j, physicsClientId=scene.cid)
        if info[2] != p.JOINT_FIXED:
            by_name[info[1].decode()] = p.getJointState(scene.hand, j, physicsClientId=scene.cid)[0]
    np.testing.assert_allclose([by_name[n] for n in d.joint_names], q, atol=1e-12)
    np.testing.assert_allclose(sim.joint_state()[0][0], q, atol=1e-12)
    urdf_order = [n for n in by_name if n not in WRIST_JOINTS]
    assert urdf_order == list(hand.description.joint_names)  # PyBullet keeps the URDF file order
    q_sim = np.array([by_name[n] for n in urdf_order])
    np.testing.assert_allclose(q_sim[sim.idx_sim_to_hand], q)
    np.testing.assert_allclose(q[sim.idx_hand_to_sim], q_sim)
    assert [n for n in by_name if n in WRIST_JOINTS] == (list(WRIST_JOINTS) if floating else [])


def test_hand_joints_must_match_the_urdf(hand):
    d = hand.description
    bad = TestHand(dataclasses.replace(d, joint_names=("joint_99.0", *d.joint_names[1:])), hand.urdf_path())
    with pytest.raises(
        AssetError, match=r"declared but not in the URDF \['joint_99.0'\].*not declared \['joint_0.0'\]"
    ):
        make_sim(bad)


def test_missing_mesh_names_the_hand(hand, tmp_path):
    urdf = tmp_path / "broken.urdf"
    urdf.write_text(hand.urdf_path().read_text().replace("link_tip.obj", "no_such_tip.obj"))
    with pytest.raises(AssetError, match="PyBullet cannot load the URDF of hand 'allegro_test'.*mesh files exist"):
        make_sim(TestHand(hand.description, urdf))


# -- drives and gravity -------------------------------------------------------------------------
def test_drive_gains_reproduce_the_implicit_spring_damper():
    pd = ImplicitPD(np.array([400.0, 5.0, 0.5]), np.array([10.0, 0.1, 0.01]), np.array([1e-4, 1e-4, 1e-4]), 1 / 120)
    c = pd.dt * (pd.damping + pd.stiffness * pd.dt)
    # one implicit-Euler step from rest: v' = dt Kp e / (I + dt Kd + dt^2 Kp), i.e. v' = pGain e / dt
    np.testing.assert_allclose(pd.position_gains / pd.dt, pd.dt * pd.stiffness / (pd.inertia + c))
    # the force limit is the spring force at the current position, whatever the velocity (drive.py) ...
    q, v, target = np.array([[0.0, 0.5, 2.0]]), np.array([[1.0, -2.0, 0.5]]), np.array([[1.0, 0.25, 1.0]])
    np.testing.assert_allclose(pd.force_limits(q, v, target), [[400.0, 1.25, 0.5]])
    # ... but the PD force at the current state on joints outside spring_limit (the floating wrist's)
    mixed = dataclasses.replace(pd, spring_limit=np.array([False, True, False]))
    pd_force = np.abs(pd.stiffness * (target - q) - (c / pd.dt) * v)
    np.testing.assert_allclose(mixed.force_limits(q, v, target), [[pd_force[0, 0], 1.25, pd_force[0, 2]]])


def test_a_finger_blocked_by_the_table_pushes_with_the_spring_force(hand):
    """A finger driven into the table presses with Kp * (q* - q) about its joint, as SAPIEN's
    implicit drive does; a plain PyBullet position motor would push with its whole effort limit.

    100 solver iterations: with 20 the finger's light links chatter against the table (PGS does
    not converge) and the balance holds only to about 10 %.
    """
    kp = 5.0
    gains = {"pd_stiffness": (kp,) * 16, "pd_damping": (0.1,) * 16}
    soft = TestHand(dataclasses.replace(hand.description, **gains), hand.urdf_path())
    sim = make_sim(soft, floating=False, self_collision=False, solver_iterations=100)
    palm_down = np.array([0.0, 0.0, 0.062, math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
    sim.set_hand_state(open_q(soft), palm_down[None])
    k = soft.description.joint_names.index("joint_1.0")
    target = open_q(soft)
    target[0, k] = 1.2
    sim.set_joint_targets(target)
    sim.step(120)
    q = sim.joint_state()[0][0, k]
    assert 0.2 < q < 1.0  # stopped by the table
    scene, ids = sim._scenes[0], sim._layout.link_ids
    joint = p.getLinkState(scene.hand, ids["link_1.0"], physicsClientId=scene.cid)
    axis = quat_to_matrix(np.r_[joint[5][3], joint[5][:3]])[:, 1]  # the joint axis: y of its child link
    finger = {ids[n] for n in ("link_1.0", "link_2.0", "link_3.0", "link_3.0_tip")}
    torque = 0.0
    for c in p.getContactPoints(bodyA=scene.hand, bodyB=scene.table, physicsClientId=scene.cid):
        if c[3] in finger:
            force = c[9] * np.array(c[7]) + c[10] * np.array(c[11]) + c[12] * np.array(c[13])
            torque += float(axis @ np.cross(np.array(c[5]) - np.array(joint[4]), force))
    assert abs(torque) == pytest.approx(kp * (1.2 - q), rel=0.01)
    assert np.linalg.norm(sim.contact_forces(["link_3.0_tip"], "table")[0, 0]) > 1.0


def test_floating_wrist_holds_the_hand_without_gravity_and_sags_with_it(hand):
    still = make_sim(hand, self_collision=False)
    still.set_hand_state(open_q(hand), UP[None])
    still.step(120)
    np.testing.assert_allclose(still.wrist_pose()[0, :3], UP[:3], atol=1e-6)
    heavy = make_sim(hand, hand_gravity=True, self_collision=False)
    heavy.set_hand_state(open_q(hand), UP[None])
    heavy.step(240)
    text = pybullet_hand_urdf(hand.urdf_text(), hand.name, floating=True).read_text()
    import xml.etree.ElementTree as ET

    moving = [
        link
        for link in ET.fromstring(text).findall("link")
        if link.get("name") not in ("ges_world", "ges_wrist_x_link", "ges_wrist_y_link")
    ]
    mass = sum(float(link.find("inertial/mass").get("value")) for link in moving)
    sag = UP[2] - heavy.wrist_pose()[0, 2]
    assert sag == pytest.approx(mass * 9.81 / SceneConfig().wrist_stiffness, rel=0.05)


# -- objects on the table -----------------------------------------------------------------------
def test_capsule_axis_is_local_x():
    sim = make_sim()
    sim.load_object(single_shape(PrimitiveShape(kind="capsule", size=(0.02, 0.05))), pose=UP)
    scene = sim._scenes[0]
    low, high = np.array(p.getAABB(scene.obj, physicsClientId=scene.cid))
    np.testing.assert_allclose(high - low, [0.14, 0.04, 0.04], atol=2e-3)


def test_mass_is_density_times_volume():
    """Mass and inertia from density: analytic for a capsule, trimesh for a convex part (PyBullet's
    own estimate would use bounding boxes)."""
    import trimesh

    capsule = single_shape(PrimitiveShape(kind="capsule", size=(0.02, 0.05)), density=1000.0)
    mesh = trimesh.creation.capsule(height=0.1, radius=0.02, count=[64, 64])
    props = shapes.mass_properties(capsule)
    assert props.mass == pytest.approx(1000.0 * mesh.volume, rel=2e-3)
    np.testing.assert_allclose(
        np.sort(props.inertia), np.sort(np.linalg.eigvalsh(mesh.moment_inertia * 1000.0)), rtol=5e-3
    )
    sim = make_sim()
    sim.load_object(capsule)
    scene = sim._scenes[0]
    dyn = p.getDynamicsInfo(scene.obj, -1, physicsClientId=scene.cid)
    assert dyn[0] == pytest.approx(props.mass)
    np.testing.assert_allclose(dyn[2], props.inertia, rtol=1e-9)


def test_convex_part_from_a_file(tmp_path):
    import trimesh

    path = tmp_path / "part.stl"  # not OBJ: converted once into the cache
    mesh = trimesh.creation.box(extents=[0.06, 0.04, 0.05])
    mesh.apply_translation([0.02, 0.0, 0.0])  # centre of mass off the object origin
    mesh.export(path)
    obj = ObjectAsset(object_id="t/convex", category="c", mesh_path=path, collision=(ConvexPart(path=path),))
    sim = make_sim()
    sim.load_object(obj)
    sim.step(60)
    pose = sim.object_pose()[0]
    assert abs(pose[2] - 0.025) < 2e-3
    assert abs(pose[0]) < 1e-3  # the object frame, not the centre of mass (at x = 0.02)
    scene = sim._scenes[0]
    assert p.getDynamicsInfo(scene.obj, -1, physicsClientId=scene.cid)[0] == pytest.approx(500.0 * 0.06 * 0.04 * 0.05)


def test_replacing_the_object_leaves_one_body_per_scene():
    """The engine-side half of the contract's object-replacement test: the old body is gone from PyBullet."""
    sim = make_sim(num_envs=2)
    sim.load_object(box_asset(object_id="t/small"))
    sim.load_object(box_asset((0.05, 0.05, 0.05), object_id="t/big"), env_ids=[1])
    for scene in sim._scenes:
        assert p.getNumBodies(physicsClientId=scene.cid) == 2  # the table and one object


def test_object_pose_round_trip_is_wxyz():
    """Poses go in and come out as wxyz, also for an object whose centre of mass and principal axes
    are off its frame; a 90 deg turn about z (read as xyzw it would be a turn about x) shows in PyBullet's AABB."""
    parts = (
        PrimitiveShape(kind="box", size=(0.05, 0.01, 0.01), pose=(0.02, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)),
        PrimitiveShape(kind="sphere", size=(0.01,), pose=(-0.03, 0.01, 0.0, 1.0, 0.0, 0.0, 0.0)),
    )
    obj = ObjectAsset(object_id="t/lopsided", category="t", mesh_path=box_asset().mesh_path, collision=parts)
    sim = make_sim(num_envs=3, gravity=0.0)
    sim.load_object(obj, pose=UP)
    rng = np.random.default_rng(5)
    quats = rng.normal(size=(3, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    poses = np.concatenate([rng.uniform(-0.2, 0.2, (3, 3)) + [0, 0, 0.5], quats], axis=1)
    sim.set_object_pose(poses)
    got = sim.object_pose()
    np.testing.assert_allclose(got[:, :3], poses[:, :3], atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(got[:, 3:] * quats, axis=1)), 1.0, atol=1e-12)
    bar = single_shape(PrimitiveShape(kind="box", size=(0.05, 0.01, 0.01)))
    sim.load_object(bar, pose=np.array([0.0, 0.0, 0.5, math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]))
    scene = sim._scenes[0]
    low, high = np.array(p.getAABB(scene.obj, physicsClientId=scene.cid))
    np.testing.assert_allclose(high - low, [0.02, 0.1, 0.02], atol=1e-3)


def test_object_errors_name_the_object(tmp_path, monkeypatch):
    sim = make_sim()
    empty = ObjectAsset(object_id="t/empty", category="t", mesh_path=box_asset().mesh_path, collision=())
    with pytest.raises(AssetError, match="object 't/empty' has no collision shapes"):
        sim.load_object(empty)
    with pytest.raises(AssetError, match=r"object 't/shape': a capsule needs 2 positive size values, got \(0.02,\)"):
        sim.load_object(single_shape(PrimitiveShape(kind="capsule", size=(0.02,))))
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(AssetError, match="convex part .*flat.obj has no volume"):
        sim.load_object(single_shape(ConvexPart(path=flat)))
    with pytest.raises(AssetError, match="cannot read convex part .*missing.obj"):
        sim.load_object(single_shape(ConvexPart(path=tmp_path / "missing.obj")))
    good = tmp_path / "good.obj"
    good.write_text(flat.read_text().replace("f 1 2 3", "v 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4"))
    monkeypatch.setattr(shapes, "_obj_file", lambda path: tmp_path / "vanished.obj")
    with pytest.raises(AssetError, match="PyBullet could not create the collision shapes of object 't/shape'"):
        sim.load_object(single_shape(ConvexPart(path=good)))


# -- contacts -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def grasped(hand):
    sim = make_sim(num_envs=2)
    grasp_scene(sim, hand)
    sim.step(20)
    yield sim
    sim.close()


def test_closing_hand_presses_the_box_with_its_fingertips(hand, grasped):
    d = hand.description
    tips = [d.finger_for_slot(slot).tip_link for slot in ("thumb", "index", "middle", "ring")]
    force = grasped.contact_forces(tips, "object")
    magnitude = np.linalg.norm(force, axis=-1)
    assert (magnitude[:, 0] > 0.1).all(), magnitude  # the thumb
    assert (magnitude[:, 1:].max(axis=1) > 0.1).all(), magnitude  # and at least one finger opposing it
    thumb, fingers = force[0, 0], force[0, 1:].sum(axis=0)
    assert float(np.dot(thumb, fingers)) < 0  # they squeeze from opposite sides
    pairs = grasped.contact_pairs(0)
    touching = {(c.link_a, c.body_b) for c in pairs if c.body_a == "hand" and c.force > 0}
    assert (tips[0], "object") in touching
    np.testing.assert_array_equal(force[0], force[1])  # two identical scenes


def test_partner_filtering(hand, grasped):
    links = list(grasped._layout.link_ids)
    on_object = grasped.contact_forces(links, "object")
    on_table = grasped.contact_forces(links, "table")
    np.testing.assert_array_equal(grasped.contact_forces(links, "any"), on_object)  # no other contact here
    assert np.abs(on_object).sum() > 0.1 and np.abs(on_table).sum() == 0.0  # the hand floats above the table
    # the box in balance: the table pushes it up with its weight plus what the hand pushes down
    box = grasped._scenes[0]
    table = np.zeros(3)
    for c in p.getContactPoints(bodyA=box.obj, bodyB=box.table, physicsClientId=box.cid):
        table += c[9] * np.array(c[7]) + c[10] * np.array(c[11]) + c[12] * np.array(c[13])
    weight = np.array([0.0, 0.0, box.obj_mass * -9.81])
    np.testing.assert_allclose(table - on_object[0].sum(axis=0) + weight, 0.0, atol=0.05 * np.abs(on_object).sum())


def test_any_partner_includes_the_hands_own_links(hand):
    """A fist in the air: fingers press on each other; those forces cancel over the whole hand."""
    sim = make_sim(hand)
    sim.set_hand_state(open_q(hand), UP[None])
    sim.set_joint_targets(hand.description.closed_pose(1.0)[None])
    sim.step(90)
    links = list(sim._layout.link_ids)
    on_any = sim.contact_forces(links, "any")[0]
    assert np.abs(on_any).max() > 0.1
    np.testing.assert_allclose(on_any.sum(axis=0), 0.0, atol=1e-6)
    assert np.abs(sim.contact_forces(links, "object")).max() == 0.0
    assert any(c.body_a == c.body_b == "hand" for c in sim.contact_pairs(0))


def test_palm_on_the_table_is_a_table_contact(hand):
    sim = make_sim(hand, self_collision=False)
    palm_down = np.array([0.0, 0.0, 0.02, math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])  # palm (+x) down
    sim.set_hand_state(open_q(hand), palm_down[None])
    sim.load_object(box_asset(), pose=np.array([0.5, 0.5, 0.03, 1.0, 0.0, 0.0, 0.0]))
    sim.set_wrist_targets((palm_down - [0, 0, 0.005, 0, 0, 0, 0])[None])  # press 5 mm into the table
    sim.step(50)
    # over the next 10 steps (PyBullet's contact point between the palm and the table may drop out for a
    # single step while the palm stays pressed: measured ~19 N on the steps before and after such a step)
    forces, pairs = [], []
    for _ in range(10):
        sim.step()
        forces.append(sim.contact_forces(["base_link"], "table")[0, 0])
        pairs.append({(c.body_a, c.link_a, c.body_b) for c in sim.contact_pairs(0)})
        assert np.abs(sim.contact_forces(["base_link"], "object")).max() == 0.0
    pressed = [i for i, f in enumerate(forces) if f[2] > 1.0]  # the table pushes the palm up ...
    assert len(pressed) >= 8, [round(f[2], 2) for f in forces]
    for i in pressed:
        assert np.linalg.norm(forces[i][:2]) <= forces[i][2] * 1.0 + 1e-6  # ... inside the friction cone (mu = 1)
        assert ("hand", "base_link", "table") in pairs[i]


# -- explosions ----------------------------------------------------------------------------------
def test_exploding_state_names_the_env(hand):
    sim = make_sim(hand, num_envs=2)
    sim.set_hand_state(open_q(hand, 2), np.tile(UP, (2, 1)))
    sim.load_object(box_asset())
    sim.step(2)
    scene = sim._scenes[1]
    p.resetBaseVelocity(scene.obj, [500.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=scene.cid)
    with pytest.raises(SimulationError, match=r"pybullet env 1: the object moves at [\d.]+ m/s"):
        sim.step()
    sim.set_object_pose(np.tile([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0], (2, 1)))
    assert sim._scenes[1] is not scene  # the blown env got a new client
    scene = sim._scenes[1]
    p.resetBaseVelocity(scene.obj, [math.nan, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=scene.cid)
    with pytest.raises(SimulationError, match="pybullet env 1: the object's pose or velocity is NaN or inf"):
        sim.step()
    sim.reset()
    scene = sim._scenes[1]
    joint = int(sim._layout.drive_ids[-1])
    p.resetJointState(scene.hand, joint, 0.0, 5 * MAX_JOINT_SPEED, physicsClientId=scene.cid)
    sim._state = None  # the joint was changed behind the backend's back
    with pytest.raises(SimulationError, match="pybullet env 1: a hand joint moves at 5e.03 after stepping"):
        sim.step()


# -- helpers ------------------------------------------------------------------------------------
def test_friction_products_equal_physx_averages():
    for hand_mu, obj_mu, table_mu in [(1.0, 1.0, 1.0), (1.0, 0.3, 0.8), (0.2, 1.5, 0.0)]:
        k_hand, k_obj, k_table = product_friction(hand_mu, obj_mu, table_mu)
        assert k_hand * k_obj == pytest.approx((hand_mu + obj_mu) / 2)
        assert k_obj * k_table == pytest.approx((obj_mu + table_mu) / 2)
        assert k_hand * k_table == pytest.approx((hand_mu + table_mu) / 2)


def test_sanitized_inertia_keeps_the_tensor():
    """Rewritten in principal axes (rpy in the inertial origin), a valid tensor is unchanged, also
    when its principal frame sits at a 90 deg pitch."""
    import xml.etree.ElementTree as ET

    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("xyz", [0.3, math.pi / 2, -0.2]).as_matrix()
    tensor = rot @ np.diag([2e-5, 3e-5, 4e-5]) @ rot.T
    names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    values = dict(
        zip(names, (tensor[0, 0], tensor[0, 1], tensor[0, 2], tensor[1, 1], tensor[1, 2], tensor[2, 2]), strict=True)
    )
    inertia = " ".join(f'{k}="{float(v)!r}"' for k, v in values.items())
    inertial = f'<inertial><origin xyz="0.1 0 0" rpy="0 0 0.4"/><mass value="0.2"/><inertia {inertia}/></inertial>'
    text = f'<robot name="r"><link name="a">{inertial}</link></robot>'
    out = ET.fromstring(sanitize_inertias(text)).find("link/inertial")
    frame = Rotation.from_euler("xyz", [float(v) for v in out.find("origin").get("rpy").split()]).as_matrix()
    diag = np.diag([float(out.find("inertia").get(k)) for k in ("ixx", "iyy", "izz")])
    expected = Rotation.from_euler("z", 0.4).as_matrix() @ tensor @ Rotation.from_euler("z", 0.4).as_matrix().T
    np.testing.assert_allclose(frame @ diag @ frame.T, expected, atol=1e-12)
    assert out.find("origin").get("xyz") == "0.1 0.0 0.0" and out.find("mass").get("value") == "0.2"


def test_inertias_are_loaded_valid(hand):
    """Every Allegro link keeps its URDF mass and gets a non-zero inertia PyBullet accepts (it zeroes
    'bad' tensors), and the virtual palm/wrist links get a gram, not PyBullet's default kilogram."""
    import xml.etree.ElementTree as ET

    tensor = np.array([[7.96e-5, 1.72e-5, 8.76e-6], [1.72e-5, 2.47e-5, 2.41e-5], [8.76e-6, 2.41e-5, 7.96e-5]])
    moments, axes = principal_moments(tensor)  # link_1.0's tensor: its eigenvalues break I1 + I2 >= I3
    assert moments.max() < moments.sum() - moments.max() and np.linalg.det(axes) > 0
    urdf = {
        link.get("name"): float(link.find("inertial/mass").get("value"))
        for link in ET.parse(hand.urdf_path()).findall("link")
        if link.find("inertial") is not None
    }
    sim = make_sim(hand)
    scene = sim._scenes[0]
    for name, j in sim._layout.link_ids.items():
        mass, _, inertia = p.getDynamicsInfo(scene.hand, j, physicsClientId=scene.cid)[:3]
        assert min(inertia) > 0, name
        assert mass == pytest.approx(urdf.get(name, 1e-3)), name
    assert {"palm", "wrist"} <= set(sim._layout.link_ids) - set(urdf)
