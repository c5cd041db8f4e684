"""HandKinematics: FK against PyBullet, Jacobians against finite differences, shapes, errors, dtypes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.errors import AssetError, UnknownNameError
from ges_core.kinematics import HandKinematics, shared_kinematics
from ges_core.registry import load_registry

from helpers_sim import pybullet_body

TIPS = ["link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip"]
PAD = [[0.012, 0.0, 0.0]] * 4  # fingertip pad points, tip-link frames

# A two-joint toy: a slider along x, then a hinge about z carrying an arm of 0.1 m along x.
TOY_URDF = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"/>
  <link name="carriage"/>
  <link name="arm"/>
  <link name="tip"/>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="carriage"/>
    <origin xyz="0 0 0.05" rpy="0.3 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-0.1" upper="0.1" effort="1" velocity="1"/>
  </joint>
  <joint name="hinge" type="revolute">
    <parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0.02 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <joint name="tip_joint" type="fixed">
    <parent link="arm"/><child link="tip"/><origin xyz="0.1 0 0"/>
  </joint>
</robot>
"""


@pytest.fixture(scope="module")
def hand():
    return load_registry().build_hand("allegro")


@pytest.fixture(scope="module")
def kin(hand) -> HandKinematics:
    return HandKinematics.from_hand(hand)


def random_q(hand, n: int, seed: int = 0) -> torch.Tensor:
    lim = hand.description.limits_array
    return torch.as_tensor(np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(n, len(lim))))


def finite_difference(kin: HandKinematics, q: torch.Tensor, links, offsets, eps: float = 1e-6) -> torch.Tensor:
    """(B, L, 3, K) central differences of ``kin.points``."""
    cols = []
    for k in range(q.shape[1]):
        dq = torch.zeros_like(q)
        dq[:, k] = eps
        cols.append((kin.points(q + dq, links, offsets) - kin.points(q - dq, links, offsets)) / (2 * eps))
    return torch.stack(cols, dim=-1)


# -- forward kinematics against PyBullet ---------------------------------------------------
@pytest.mark.sim
def test_link_poses_match_pybullet(hand, kin):
    pytest.importorskip("pybullet")
    with pybullet_body(hand.urdf_path()) as (pybullet, client, body, infos):
        joint_id = {i[1].decode(): i[0] for i in infos}
        link_id = {i[12].decode(): i[0] for i in infos}
        links = sorted(link_id)  # every link but the base, which is the frame of both
        q = random_q(hand, 6, seed=1)
        ours = kin.link_poses(q, links).numpy()
        for b in range(len(q)):
            for name, value in zip(hand.description.joint_names, q[b].tolist(), strict=True):
                pybullet.resetJointState(body, joint_id[name], value, physicsClientId=client)
            for li, name in enumerate(links):
                state = pybullet.getLinkState(
                    body, link_id[name], computeForwardKinematics=True, physicsClientId=client
                )
                rot = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
                assert np.linalg.norm(ours[b, li, :3, 3] - state[4]) < 1e-3, name
                assert np.abs(ours[b, li, :3, :3] - rot).max() < 1e-3, name


def test_joint_order_is_by_name(hand, kin):
    """A kinematics built with the joints in another order gives the same poses for the same named values."""
    names = list(hand.description.joint_names)
    perm = np.random.default_rng(3).permutation(len(names))
    shuffled = HandKinematics(hand.urdf_text(), [names[i] for i in perm])
    q = random_q(hand, 3)
    torch.testing.assert_close(shuffled.points(q[:, perm], TIPS), kin.points(q, TIPS))
    q_chain = q[:, kin.idx_hand_to_chain]
    torch.testing.assert_close(q_chain[:, kin.idx_chain_to_hand], q)


def test_base_link_is_identity_and_tip_offsets_apply(kin):
    q = torch.zeros(2, kin.num_joints)
    assert kin.base_link == "base_link"
    torch.testing.assert_close(
        kin.link_poses(q, ["base_link"])[:, 0], torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    )
    poses = kin.link_poses(q, TIPS)
    pads = kin.points(q, TIPS, PAD)
    expected = poses[..., :3, 3] + poses[..., :3, 0] * 0.012  # offset along each tip frame's x axis
    torch.testing.assert_close(pads, expected)


# -- Jacobians ----------------------------------------------------------------------------
def test_jacobians_match_finite_differences(hand, kin):
    q = random_q(hand, 4, seed=2)
    links = [*TIPS, "link_5.0", "palm"]
    offsets = torch.tensor([*PAD, [0.01, -0.02, 0.03], [0.0, 0.0, 0.1]])
    jac = kin.jacobians(q, links, offsets)
    assert jac.shape == (4, 6, 3, 16)
    torch.testing.assert_close(jac, finite_difference(kin, q, links, offsets), atol=1e-7, rtol=0)
    assert jac[:, -1].abs().max() == 0  # the palm is fixed to the base


def test_jacobians_match_autograd(hand, kin):
    q = random_q(hand, 2, seed=4).requires_grad_(True)
    points = kin.points(q, TIPS, PAD)
    rows = [torch.autograd.grad(points[:, 1, c].sum(), q, retain_graph=True)[0] for c in range(3)]
    torch.testing.assert_close(kin.jacobians(q.detach(), TIPS, PAD)[:, 1], torch.stack(rows, dim=1), atol=1e-7, rtol=0)


def test_prismatic_and_revolute_columns():
    kin = HandKinematics(TOY_URDF, ["hinge", "slide"])
    q = torch.tensor([[0.4, 0.03], [-1.0, -0.05]], dtype=torch.float64)
    offsets = torch.tensor([[0.0, 0.01, 0.0]])
    jac = kin.jacobians(q, ["tip"], offsets)
    torch.testing.assert_close(jac, finite_difference(kin, q, ["tip"], offsets), atol=1e-8, rtol=0)
    torch.testing.assert_close(jac[:, 0, :, 1], torch.tensor([[1.0, 0.0, 0.0]] * 2, dtype=torch.float64))


def test_batch_rows_are_independent(hand, kin):
    q = random_q(hand, 5, seed=5)
    one = torch.cat([kin.jacobians(q[i : i + 1], TIPS, PAD) for i in range(5)])
    torch.testing.assert_close(kin.jacobians(q, TIPS, PAD), one)
    per_row_offsets = torch.tensor(PAD, dtype=torch.float64).expand(5, 4, 3)
    torch.testing.assert_close(kin.points(q, TIPS, per_row_offsets), kin.points(q, TIPS, PAD))


# -- dtype and device ---------------------------------------------------------------------
def test_to_float32_returns_a_copy(hand, kin):
    q = random_q(hand, 2)
    k32 = kin.to(torch.float32)
    assert kin.dtype == torch.float64 and k32.dtype == torch.float32
    assert k32.points(q, TIPS).dtype == torch.float32
    assert kin.points(q.float(), TIPS).dtype == torch.float64  # inputs follow the kinematics' dtype
    torch.testing.assert_close(k32.points(q, TIPS).double(), kin.points(q, TIPS), atol=1e-5, rtol=0)
    assert k32.jacobians(q, TIPS).dtype == torch.float32


def test_shapes(kin):
    q = torch.zeros(3, kin.num_joints)
    assert kin.link_poses(q, TIPS[:2]).shape == (3, 2, 4, 4)
    assert kin.points(q, TIPS).shape == (3, 4, 3)
    assert kin.jacobians(q, ["base_link"]).abs().max() == 0


# -- errors -------------------------------------------------------------------------------
def test_unknown_link_lists_known_links(kin):
    with pytest.raises(
        UnknownNameError, match=r"unknown link 'link_3.0_tipp'\. Did you mean 'link_3.0_tip'\?.*base_link"
    ):
        kin.points(torch.zeros(1, 16), ["link_3.0_tipp"])


def test_links_as_one_string_is_rejected(kin):
    with pytest.raises(TypeError, match="links must be a sequence of link names, got the string 'palm'"):
        kin.link_poses(torch.zeros(1, 16), "palm")


def test_no_links_is_rejected(kin):
    with pytest.raises(ValueError, match="links is empty; name at least one link"):
        kin.jacobians(torch.zeros(1, 16), [])


@pytest.mark.parametrize("shape", [(16,), (2, 15), (1, 2, 16)])
def test_wrong_q_shape(kin, shape):
    with pytest.raises(ValueError, match=r"q must have shape \(B, 16\) in the order joint_0.0, .*; got"):
        kin.points(torch.zeros(shape), TIPS)


def test_wrong_offsets_shape(kin):
    with pytest.raises(ValueError, match=r"offsets must have shape \(4, 3\) or \(2, 4, 3\); got \(3, 3\)"):
        kin.points(torch.zeros(2, 16), TIPS, torch.zeros(3, 3))


def test_joint_names_must_match_the_urdf():
    with pytest.raises(AssetError, match=r"not in the URDF \['elbow'\], missing \['slide'\], repeated \[\]"):
        HandKinematics(TOY_URDF, ["hinge", "elbow"])
    with pytest.raises(AssetError, match=r"each movable URDF joint once: .* repeated \['hinge'\]"):
        HandKinematics(TOY_URDF, ["hinge", "slide", "hinge"])


def test_malformed_urdf():
    with pytest.raises(AssetError, match="pytorch_kinematics cannot build a chain from this URDF"):
        HandKinematics("<robot name='x'><link", ["a"])


def test_shared_kinematics_is_built_once_per_hand_and_agrees_with_a_fresh_one():
    registry = load_registry()
    allegro, again = registry.build_hand("allegro"), registry.build_hand("allegro")
    shared = shared_kinematics(allegro)
    assert shared_kinematics(again) is shared  # same URDF and joint order: the same object
    assert shared_kinematics(registry.build_hand("shadow")) is not shared
    q = torch.as_tensor(allegro.description.closed_pose(0.4))[None]
    links = list(allegro.description.tip_links)
    torch.testing.assert_close(shared.link_poses(q, links), HandKinematics.from_hand(allegro).link_poses(q, links))
