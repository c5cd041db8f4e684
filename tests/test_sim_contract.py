"""The SimBackend contract, checked the same way on every built-in backend.

Tests that used to be written once per backend (test_sim_sapien.py, test_sim_pybullet.py) with the
same scene and the same references: forward kinematics from pytorch-kinematics, rest heights of
primitives, wrist driving and reset semantics. Engine-specific behaviour stays in the per-backend files.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from ges_core.objects.asset import ObjectAsset, PrimitiveShape
from ges_core.transforms import quat_to_matrix
from ges_core.urdf import euler_xyz_to_quat
from ges_plugins.sims.pybullet.backend import REST_MARGIN as PYBULLET_REST_MARGIN
from ges_plugins.sims.pybullet.backend import PybulletBackend
from ges_plugins.sims.sapien.backend import SapienBackend
from ges_plugins.sims.sapien.loading import REST_MARGIN as SAPIEN_REST_MARGIN

from helpers_sim import UP, allegro_test_hand, box_asset, loaded_sim, open_q

pytestmark = pytest.mark.sim

BACKENDS = {"sapien": (SapienBackend, SAPIEN_REST_MARGIN), "pybullet": (PybulletBackend, PYBULLET_REST_MARGIN)}


@pytest.fixture(scope="module")
def hand():
    return allegro_test_hand()


@pytest.fixture(params=sorted(BACKENDS))
def backend(request):
    """(make_sim, rest margin) of one backend: ``make_sim(hand=None, floating=True, **scene)``."""
    cls, margin = BACKENDS[request.param]
    return partial(loaded_sim, cls), margin


@pytest.mark.parametrize("floating", [True, False])
def test_link_poses_match_pytorch_kinematics(backend, hand, floating):
    """Every link at random joints and random base poses, against pytorch-kinematics composed with the base."""
    import pytorch_kinematics as pk
    import torch

    make_sim, _ = backend
    chain = pk.build_chain_from_urdf(hand.urdf_path().read_bytes()).to(dtype=torch.float64)
    links = [n for n in chain.get_frame_names() if n != chain._root.name]
    rng = np.random.default_rng(7)
    lim = hand.description.limits_array
    qs = rng.uniform(lim[:, 0], lim[:, 1], size=(3, len(lim)))
    order = [hand.description.joint_names.index(n) for n in chain.get_joint_parameter_names()]
    fk = chain.forward_kinematics(torch.as_tensor(qs[:, order]))
    sim = make_sim(hand, floating=floating)
    for i, q in enumerate(qs):
        wrist = np.r_[rng.uniform(-0.3, 0.3, 3), euler_xyz_to_quat(rng.uniform(-2.5, 2.5, 3))]
        sim.set_hand_state(q[None], wrist[None])
        got = sim.link_poses(links)[0]
        np.testing.assert_allclose(sim.wrist_pose()[0, :3], wrist[:3], atol=1e-5)
        assert abs(float(np.dot(sim.wrist_pose()[0, 3:], wrist[3:]))) > 1 - 1e-6  # PyBullet's frames are float32
        rot = quat_to_matrix(wrist[3:])
        for j, name in enumerate(links):
            expected = fk[name].get_matrix()[i].numpy()
            np.testing.assert_allclose(got[j, :3], wrist[:3] + rot @ expected[:3, 3], atol=1e-3, err_msg=name)
            np.testing.assert_allclose(quat_to_matrix(got[j, 3:]), rot @ expected[:3, :3], atol=2e-3, err_msg=name)


def test_wrist_targets_move_the_base(backend, hand):
    make_sim, _ = backend
    sim = make_sim(hand)
    sim.set_hand_state(open_q(hand), UP[None])
    goal = np.r_[0.1, -0.05, 0.4, euler_xyz_to_quat(np.array([0.3, -0.4, 2.9]))]
    sim.set_wrist_targets(goal[None])
    sim.step(240)
    got = sim.wrist_pose()[0]
    np.testing.assert_allclose(got[:3], goal[:3], atol=2e-3)
    assert abs(float(np.dot(got[3:], goal[3:]))) > 0.9999


def test_default_pose_rests_the_object_on_the_table(backend):
    make_sim, margin = backend
    sim = make_sim()
    sim.load_object(box_asset((0.03, 0.03, 0.05)))
    np.testing.assert_allclose(sim.object_pose()[0], [0, 0, 0.05 + margin, 1, 0, 0, 0], atol=1e-6)
    sim.step(60)
    assert abs(sim.object_pose()[0, 2] - 0.05) < 1e-3


def test_dropped_box_rests_at_half_height(backend):
    make_sim, _ = backend
    sim = make_sim()
    sim.load_object(box_asset((0.04, 0.03, 0.02)), pose=np.array([0.1, 0.0, 0.2, 1.0, 0.0, 0.0, 0.0]))
    sim.step(180)
    pose = sim.object_pose()[0]
    assert abs(pose[2] - 0.02) < 2e-3
    np.testing.assert_allclose(pose[:2], [0.1, 0.0], atol=2e-3)
    np.testing.assert_allclose(np.abs(pose[3]), 1.0, atol=1e-4)


def test_a_fixed_object_stays_put_and_still_reports_contacts(backend, hand):
    """load_object(fixed=True): no fall under gravity, no push from a hand driven into it, contacts read as usual;
    the next load_object is free again (the same box dropped from the same pose falls)."""
    make_sim, _ = backend
    sim = make_sim(hand)
    start = np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0])  # 10 cm above the table
    sim.load_object(box_asset(), pose=start, fixed=True)
    palm_down = np.array([0.0, 0.0, 0.3, 0.0, 1.0, 0.0, 0.0])  # well above, then driven down through the box
    sim.set_hand_state(open_q(hand), palm_down[None])
    pushed = 0.0
    for i in range(90):
        sim.set_wrist_targets((palm_down - [0, 0, 0.25 * min(1.0, (i + 1) / 60), 0, 0, 0, 0])[None])
        sim.step()
        pushed = max(pushed, float(np.abs(sim.contact_forces(["base_link", *hand.description.tip_links])[0]).max()))
    np.testing.assert_allclose(sim.object_pose()[0], start, atol=1e-6)
    assert pushed > 1.0  # the hand did push on it, N
    sim.load_object(box_asset(), pose=start)
    sim.step(60)
    assert sim.object_pose()[0, 2] < 0.05


@pytest.mark.parametrize(
    ("shape", "rest_z"),
    [
        (PrimitiveShape(kind="sphere", size=(0.03,)), 0.03),
        (PrimitiveShape(kind="capsule", size=(0.02, 0.05)), 0.02),  # axis along local x: it lies down
        (PrimitiveShape(kind="cylinder", size=(0.02, 0.05)), 0.02),  # standing on an end would be 0.05
        (PrimitiveShape(kind="box", size=(0.02, 0.02, 0.02), pose=(0, 0, 0.03, 1, 0, 0, 0)), -0.01),
    ],
)
def test_primitives_fall_to_their_physical_rest_height(backend, shape, rest_z):
    make_sim, _ = backend
    sim = make_sim()
    obj = ObjectAsset(object_id="t/p", category="p", mesh_path=box_asset().mesh_path, collision=(shape,))
    sim.load_object(obj, pose=np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]))
    sim.step(150)
    assert abs(sim.object_pose()[0, 2] - rest_z) < 2e-3


def test_reset_without_a_base_pose_returns_to_the_origin(backend, hand):
    make_sim, _ = backend
    sim = make_sim(hand)
    sim.set_wrist_targets(UP[None])
    sim.set_joint_targets(open_q(hand) + 0.2)
    sim.step(30)
    assert sim.wrist_pose()[0, 2] > 0.1
    sim.reset()
    np.testing.assert_allclose(sim.wrist_pose()[0], [0, 0, 0, 1, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(sim.joint_state()[0], open_q(hand), atol=1e-6)
