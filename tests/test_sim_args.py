"""ges_core.sim_args: the argument checks and wrist conversions every backend goes through (pure, no engine)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.errors import ArrayError, ConfigError
from ges_core.sim_args import (
    check_env_rows,
    env_id_list,
    unit_quaternions,
    unwrap_angles,
    wrist_coordinates,
)
from ges_core.transforms import euler_xyz_to_quat, quat_to_euler_xyz, quat_to_matrix

TURN = 2 * np.pi


def test_unwrap_moves_by_whole_turns_to_the_nearest_angle_within_the_limits():
    rng = np.random.default_rng(0)
    reference = rng.uniform(-TURN, TURN, (2000, 3))
    angles = rng.uniform(-np.pi, np.pi, (2000, 3))
    out = unwrap_angles(angles, reference)
    turns = (out - angles) / TURN
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-12)  # the same rotation
    assert np.abs(out).max() <= TURN  # inside the hinges' +-2 pi
    inside = np.abs(angles + TURN * np.round((reference - angles) / TURN)) <= TURN
    assert np.abs(out - reference)[inside].max() <= np.pi + 1e-12  # the nearest turn where the limits allow it
    assert inside.mean() > 0.6 and not inside.all()  # both branches ran


def test_unwrap_keeps_an_angle_near_its_reference_bit_for_bit():
    angles = np.random.default_rng(1).uniform(-3.0, 3.0, (100, 3))
    assert np.array_equal(unwrap_angles(angles, angles + 0.1), angles)


def test_unwrap_examples():
    """Across +-pi the target keeps turning the same way; past 2 pi it turns back by one turn."""
    np.testing.assert_allclose(unwrap_angles(np.array([[-3.1, 0.0, 3.1]]), np.array([[3.1, 0.0, -3.1]])),
                               [[-3.1 + TURN, 0.0, 3.1 - TURN]])  # fmt: skip
    np.testing.assert_allclose(unwrap_angles(np.array([[0.3]]), np.array([[6.2]])), [[0.3]])  # 0.3 + 2 pi > 2 pi


def test_wrist_coordinates_rebuild_the_base_rotation():
    rng = np.random.default_rng(2)
    quats = rng.normal(size=(50, 4))  # not normalised: the conversion does not care
    pose = np.concatenate([rng.uniform(-1, 1, (50, 3)), quats], axis=1)
    coords = wrist_coordinates(pose)
    assert coords.shape == (50, 6) and np.array_equal(coords[:, :3], pose[:, :3])
    assert np.array_equal(coords[:, 3:], quat_to_euler_xyz(quats))
    rebuilt = quat_to_matrix(euler_xyz_to_quat(coords[:, 3:]))
    np.testing.assert_allclose(rebuilt, quat_to_matrix(quats / np.linalg.norm(quats, axis=1, keepdims=True)), atol=1e-9)
    other_turn = coords[:, 3:] - TURN * np.sign(coords[:, 3:])  # the same angles one turn away, within +-2 pi
    np.testing.assert_allclose(wrist_coordinates(pose, other_turn)[:, 3:], other_turn, atol=1e-12)


def test_a_target_stream_through_gimbal_lock_stays_continuous():
    """Base rotations turning 0.5 degrees a step through ry = +-pi/2 (both signs, several rx + rz), each converted
    against the previous targets as a backend does: every set rebuilds its rotation, and no angle moves more than
    the turn asks (the principal values alone keep ry within +-pi/2 and jump rx and rz by pi at the crossing)."""
    from scipy.spatial.transform import Rotation

    step = np.radians(0.5)
    for sign in (1.0, -1.0):
        for twist in (0.0, 0.7, -2.4):
            turns = Rotation.from_euler("y", np.arange(-20, 21)[:, None] * step) * Rotation.from_euler(
                "XYZ", [twist, sign * np.pi / 2, 0.0]
            )
            quats = turns.as_quat()[:, [3, 0, 1, 2]]
            targets = wrist_coordinates(np.r_[0.0, 0.0, 0.3, quats[0]][None])[:, 3:]
            for quat, matrix in zip(quats[1:], turns[1:].as_matrix(), strict=True):
                previous = targets
                targets = wrist_coordinates(np.r_[0.0, 0.0, 0.3, quat][None], previous)[:, 3:]
                np.testing.assert_allclose(quat_to_matrix(euler_xyz_to_quat(targets[0])), matrix, atol=1e-7)
                assert np.abs(targets - previous).max() < 2 * step, (sign, twist, previous, targets)
            principal = quat_to_euler_xyz(quats)  # ry never past pi/2: rx and rz jump 2.4-3.1 rad at the crossing
            assert np.abs(principal[:, 1]).max() <= np.pi / 2 and np.abs(np.diff(principal, axis=0)).max() > 2.0


def test_unit_quaternions_divide_by_the_norm_and_keep_the_position():
    pose = np.array([[0.1, 0.2, 0.3, 2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]])
    np.testing.assert_array_equal(unit_quaternions(pose), [[0.1, 0.2, 0.3, 1, 0, 0, 0], [0, 0, 0, 0.5, 0.5, 0.5, 0.5]])
    np.testing.assert_array_equal(unit_quaternions(pose[1]), [0, 0, 0, 0.5, 0.5, 0.5, 0.5])


def test_env_ids_come_as_a_list_of_ints():
    assert env_id_list(None, 3, "x") == [0, 1, 2]
    assert env_id_list(torch.tensor([2, 0]), 3, "x") == [2, 0]
    assert env_id_list(np.array([], dtype=np.int64), 3, "x") == []
    with pytest.raises(ConfigError, match=r"x.reset: env ids \[3\] out of range for num_envs=3 \(valid: 0..2\)"):
        env_id_list([3], 3, "x.reset")


def test_rows_must_match_env_ids():
    check_env_rows(np.zeros((2, 4)), None, [0], "x", "q")  # no env_ids: the full shape check decides
    check_env_rows(np.zeros(4), [0], [0], "x", "q")  # not 2-D: the same
    check_env_rows(np.zeros((1, 4)), [2], [2], "x", "q")
    with pytest.raises(ArrayError, match=r"x: q has 2 rows but env_ids names 1 env\(s\) \[2\]; give one row per"):
        check_env_rows(np.zeros((2, 4)), [2], [2], "x", "q")
