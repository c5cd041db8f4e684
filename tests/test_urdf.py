"""URDF helpers and pose conversions, cross-checked against scipy and pytorch-kinematics."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.errors import AssetError
from ges_core.transforms import euler_xyz_to_quat, pose_to_matrix
from ges_core.urdf import (
    WRIST_JOINTS,
    add_floating_base,
    root_link,
    strip_render_data,
)

from conftest import EXAMPLE_HAND_PKG

GRIPPER = (EXAMPLE_HAND_PKG / "ges_example_hand" / "gripper.urdf").read_text()


def test_floating_base_moves_root_like_the_pose():
    """FK of the floating URDF equals the wrist pose we command through the six virtual joints."""
    import pytorch_kinematics as pk

    text = add_floating_base(GRIPPER)
    assert root_link(text) == "ges_world"
    chain = pk.build_chain_from_urdf(text).to(dtype=torch.float64)
    names = chain.get_joint_parameter_names()
    assert names[:6] == list(WRIST_JOINTS)
    rng = np.random.default_rng(3)
    xyz, angles = rng.normal(size=3), rng.uniform(-1, 1, size=3)
    q = torch.zeros(1, len(names), dtype=torch.float64)
    q[0, :3], q[0, 3:6] = torch.as_tensor(xyz), torch.as_tensor(angles)
    palm = chain.forward_kinematics(q)["palm"].get_matrix()[0].numpy()
    expected = pose_to_matrix(np.concatenate([xyz, euler_xyz_to_quat(angles)]))
    assert np.allclose(palm, expected, atol=1e-9)


def test_strip_render_data_removes_materials_and_visuals():
    text = GRIPPER.replace(
        "</link>", '<visual><geometry><box size="1 1 1"/></geometry><material name="m"/></visual></link>', 1
    )
    out = strip_render_data(text)
    assert "<material" not in out and "<visual" not in out
    assert "<visual" in strip_render_data(text, keep_visuals=True)


@pytest.mark.parametrize(
    ("text", "message"),
    [("<robot><link name='a'>", "not valid XML"), ("<model/>", "expected <robot>")],
)
def test_bad_urdf_text(text, message):
    with pytest.raises(AssetError, match=message):
        root_link(text)


def test_two_roots_rejected():
    with pytest.raises(AssetError, match="exactly one root link"):
        root_link("<robot name='r'><link name='a'/><link name='b'/></robot>")
