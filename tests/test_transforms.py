"""ges_core.transforms (numpy) and its torch twin ges_core.transforms_torch: against scipy, and against each other."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from ges_core import transforms as tf
from ges_core import transforms_torch as tt


def _wxyz(r: Rotation) -> np.ndarray:
    return r.as_quat()[..., [3, 0, 1, 2]]


def _unit_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _canonical(pose: np.ndarray) -> np.ndarray:  # q and -q are one rotation: compare with w >= 0
    return np.concatenate([pose[..., :3], pose[..., 3:] * np.sign(pose[..., 3:4])], axis=-1)


# -- numpy against scipy -------------------------------------------------------------------------
def test_euler_matches_scipy_intrinsic_xyz():
    angles = np.random.default_rng(0).uniform(-1.5, 1.5, size=(200, 3))
    ours = tf.euler_xyz_to_quat(angles)
    ref = Rotation.from_euler("XYZ", angles).as_quat()[:, [3, 0, 1, 2]]
    assert np.allclose(np.abs((ours * ref).sum(axis=1)), 1.0)
    assert np.allclose(tf.quat_to_euler_xyz(ours), angles)


@pytest.mark.parametrize("rows", [1, 50])  # the Python-float path and the numpy path
def test_euler_at_and_near_gimbal_lock_gives_back_the_rotation(rows):
    """At ry = +-pi/2 only rx + rz (or rx - rz) is defined: the angles must still give the rotation back, and at the
    lock itself equal scipy's, which sets rz to 0 there. Before the lock was taken, such rotations came back turned by
    up to 180 degrees about the shared axis (the Inspire hand's palm-down start: 90)."""
    rng = np.random.default_rng(11)
    angles = rng.uniform(-np.pi, np.pi, size=(rows, 3))
    angles[:, 1] = np.pi / 2 * rng.choice([-1.0, 1.0], size=rows)
    at_lock = Rotation.from_euler("XYZ", angles)
    quarter = np.pi / 2 * rng.integers(-2, 3, size=(rows, 3))  # axis-aligned: exact zeros in the matrix
    quarter[:, 1] = np.pi / 2 * rng.choice([-1.0, 1.0], size=rows)
    axis_aligned = Rotation.from_matrix(np.round(Rotation.from_euler("XYZ", quarter).as_matrix()))
    near = angles.copy()
    near[:, 1] -= np.sign(near[:, 1]) * 10.0 ** -rng.uniform(4, 16, size=rows)
    for rotation in (at_lock, axis_aligned, Rotation.from_euler("XYZ", near)):
        ours = tf.quat_to_euler_xyz(_wxyz(rotation))
        back = tf.quat_to_matrix(tf.euler_xyz_to_quat(ours))
        np.testing.assert_allclose(back, rotation.as_matrix(), atol=1e-7)
    with pytest.warns(UserWarning, match="Gimbal lock"):
        expected = at_lock.as_euler("XYZ")
    ours = tf.quat_to_euler_xyz(_wxyz(at_lock))
    turns = (ours - expected + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(turns[:, [0, 2]]).max() < 1e-9 and np.abs(turns[:, 1]).max() < 1e-7


@pytest.mark.parametrize("rows", [0, 1, 2, 5, 8, 9, 64])
def test_euler_few_rows_path_is_the_numpy_path_bit_for_bit(rows):
    """Up to 8 rows quat_to_euler_xyz computes on Python floats; it must give the numpy path's exact bits
    (signed zeros too): PyBullet's wrist targets are float64 and must not change by one ulp."""
    rng = np.random.default_rng(rows)
    s = np.sqrt(0.5)  # [s, 0, s, 0]: gimbal lock, ry = pi / 2
    special = np.array([[1, 0, 0, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [0.5, 0.5, 0.5, 0.5], [s, 0, s, 0], [s, 0, -s, 0]])
    for quats in [*rng.normal(size=(2000 // max(rows, 1), rows, 4)), np.resize(special, (rows, 4))]:
        got, expected = tf.quat_to_euler_xyz(quats), tf._euler_xyz_numpy(quats)
        assert got.shape == (rows, 3) and np.array_equal(got.view(np.int64), expected.view(np.int64))
    assert tf.quat_to_euler_xyz(np.resize(special, (2, 3, 4))).shape == (2, 3, 3)  # any leading shape


def test_pose_matrix_round_trip():
    rng = np.random.default_rng(1)
    quat = _wxyz(Rotation.random(50, random_state=2))
    quat *= np.sign(quat[:, :1])
    pose = np.concatenate([rng.normal(size=(50, 3)), quat], axis=1)
    assert np.allclose(tf.matrix_to_pose(tf.pose_to_matrix(pose)), pose)


def test_quat_mul_and_both_matrix_forms_match_scipy():
    a, b = Rotation.random(20, random_state=3), Rotation.random(20, random_state=4)
    np.testing.assert_allclose(tf.quat_to_matrix(tf.quat_mul(_wxyz(a), _wxyz(b))), (a * b).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(tf.unit_quat_to_matrix(_wxyz(a)), a.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(tf.quat_to_matrix(3.0 * _wxyz(a)), a.as_matrix(), atol=1e-12)  # normalised first


def test_rotation_vectors_match_scipy():
    r = Rotation.random(50, random_state=5)
    q = _wxyz(r)
    np.testing.assert_allclose(tf.quat_to_rotvec(q), r.as_rotvec(), atol=1e-12)
    np.testing.assert_allclose(tf.quat_to_rotvec(-q), r.as_rotvec(), atol=1e-12)  # q and -q: one rotation
    np.testing.assert_allclose(np.abs((tf.rotvec_to_quat(r.as_rotvec()) * q).sum(-1)), 1.0)
    np.testing.assert_allclose(tf.quat_to_matrix(tf.quat_conj(q)), r.inv().as_matrix(), atol=1e-12)


def test_pose_composition_and_interpolation_against_scipy():
    rng = np.random.default_rng(0)
    a, b = (np.concatenate([rng.normal(size=3), _wxyz(Rotation.random(random_state=s))]) for s in (1, 2))
    np.testing.assert_allclose(_canonical(tf.compose(a, tf.relative(a, b))), _canonical(b), atol=1e-12)
    np.testing.assert_allclose(_canonical(tf.interpolate_pose(a, b, 0.0)), _canonical(a), atol=1e-12)
    np.testing.assert_allclose(_canonical(tf.interpolate_pose(a, b, 1.0)), _canonical(b), atol=1e-12)
    mid = tf.interpolate_pose(a, b, 0.5)
    ra, rb, rm = (Rotation.from_quat(np.roll(p[3:], -1)) for p in (a, b, mid))
    assert (ra.inv() * rm).magnitude() == pytest.approx((ra.inv() * rb).magnitude() / 2)
    np.testing.assert_allclose(mid[:3], (a[:3] + b[:3]) / 2)


@pytest.mark.parametrize("direction", [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0.3, -0.5, 0.2]])
def test_quat_from_z_axis_turns_z_onto_the_direction(direction):
    d = np.asarray(direction, dtype=float)
    rot = Rotation.from_quat(np.roll(tf.quat_from_z_axis(d), -1))
    np.testing.assert_allclose(rot.apply([0.0, 0.0, 1.0]), d / np.linalg.norm(d), atol=1e-12)


def test_quaternion_orders_swap_back_and_forth():
    q = _unit_quats(np.random.default_rng(6), 5)
    assert np.array_equal(tf.xyzw_to_wxyz(tf.wxyz_to_xyzw(q)), q)
    np.testing.assert_array_equal(tf.wxyz_to_xyzw(q)[:, 3], q[:, 0])


# -- the torch twin against scipy and against numpy ------------------------------------------------
def test_torch_rotations_match_scipy():
    rng = np.random.default_rng(0)
    r = Rotation.random(50, random_state=rng)
    q = torch.as_tensor(_wxyz(r))
    assert np.allclose(tt.quat_to_rotvec(q).numpy(), r.as_rotvec(), atol=1e-9)
    assert np.allclose(tt.quat_to_rotvec(-q).numpy(), r.as_rotvec(), atol=1e-9)
    back = tt.rotvec_to_quat(torch.as_tensor(r.as_rotvec()))
    assert np.allclose((back * q).sum(-1).abs().numpy(), 1.0)
    s = Rotation.random(50, random_state=rng)
    prod = tt.quat_mul(q, torch.as_tensor(_wxyz(s)))
    assert np.allclose(np.abs((prod.numpy() * _wxyz(r * s)).sum(-1)), 1.0)
    v = rng.normal(size=(50, 3))
    assert np.allclose(tt.quat_rotate(q, torch.as_tensor(v)).numpy(), r.apply(v))
    assert np.allclose(tt.quat_to_rotvec(tt.quat_mul(q, tt.quat_conj(q))).numpy(), 0.0, atol=1e-7)
    assert np.allclose(tt.quat_to_rotvec(tt.rotvec_to_quat(torch.zeros(1, 3, dtype=torch.float64))).numpy(), 0.0)


def test_numpy_functions_match_their_torch_twins():
    rng = np.random.default_rng(0)
    q, p = _unit_quats(rng, 40), _unit_quats(rng, 40)
    q[:5, 0] = -np.abs(q[:5, 0])  # w < 0: the rotation vector takes the shorter way round
    q[5] = [1.0, 0.0, 0.0, 0.0]
    q[6], q[7] = [-0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]  # half turns: -0.0 is not flipped either
    v = rng.normal(size=(40, 3))
    v[:3] *= 1e-12  # below the small-angle switch
    tq, tp, tv = (torch.as_tensor(x) for x in (q, p, v))
    np.testing.assert_allclose(tf.quat_mul(q, p), tt.quat_mul(tq, tp).numpy(), atol=1e-15)
    np.testing.assert_allclose(tf.quat_conj(q), tt.quat_conj(tq).numpy())
    np.testing.assert_allclose(tf.quat_to_rotvec(q), tt.quat_to_rotvec(tq).numpy(), atol=1e-14)
    np.testing.assert_allclose(tf.rotvec_to_quat(v), tt.rotvec_to_quat(tv).numpy(), atol=1e-15)
    rot = tf.unit_quat_to_matrix(q)
    np.testing.assert_allclose((rot @ v[..., None])[..., 0], tt.quat_rotate(tq, tv).numpy(), atol=1e-14)
    np.testing.assert_allclose(v[:, None] @ rot, tt.quat_rotate(tt.quat_conj(tq), tv).numpy()[:, None], atol=1e-14)
    long = q * 1.5  # not unit: still the same linear map as quat_rotate
    np.testing.assert_allclose(
        (tf.unit_quat_to_matrix(long) @ v[..., None])[..., 0], tt.quat_rotate(torch.as_tensor(long), tv).numpy(),
        atol=1e-13,
    )  # fmt: skip


def test_the_two_pose_interpolations_give_one_pose():
    """numpy's interpolate_pose (arccos slerp, one pose) and torch's (rotation vectors, batched) agree."""
    rng = np.random.default_rng(7)
    a = np.concatenate([rng.normal(size=(30, 3)), _unit_quats(rng, 30)], axis=1)
    b = np.concatenate([rng.normal(size=(30, 3)), _unit_quats(rng, 30)], axis=1)
    for s in (0.0, 0.25, 0.5, 1.0):
        ours = np.stack([tf.interpolate_pose(x, y, s) for x, y in zip(a, b, strict=True)])
        twin = tt.interpolate_pose(torch.as_tensor(a), torch.as_tensor(b), s).numpy()
        np.testing.assert_allclose(_canonical(ours), _canonical(twin), atol=1e-12)


def test_matrix_columns_round_trip_and_noisy_columns_give_a_rotation() -> None:
    """The two columns of scipy's matrices come back as those matrices; perturbed columns (observation noise) give a
    proper rotation whose first column keeps the given direction; zero, parallel or NaN columns give NaN."""
    rots = Rotation.random(500, random_state=7).as_matrix()
    cols = tf.matrix_columns(rots)
    np.testing.assert_array_equal(cols, np.concatenate([rots[:, :, 0], rots[:, :, 1]], axis=1))
    np.testing.assert_allclose(tf.columns_to_matrix(cols), rots, atol=1e-14)
    noisy = tf.columns_to_matrix(cols + np.random.default_rng(0).normal(scale=0.002, size=cols.shape))
    np.testing.assert_allclose(noisy @ noisy.transpose(0, 2, 1), np.broadcast_to(np.eye(3), noisy.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(noisy), 1.0, atol=1e-12)
    angle = Rotation.from_matrix(noisy).inv() * Rotation.from_matrix(rots)
    assert angle.magnitude().max() < 0.02  # a few times the noise
    bad = tf.columns_to_matrix(np.array([[0, 0, 0, 0, 1, 0], [1, 0, 0, -3, 0, 0], [np.nan, 0, 0, 0, 1, 0.0]]))
    assert np.isnan(bad).all()
