"""Poses and rotations in numpy float64: the one module (its torch twin: :mod:`ges_core.transforms_torch`).

Conventions everywhere: a pose is ``(..., 7)``, position x, y, z in metres then a unit quaternion **w, x, y, z**;
``a * b`` composes ``b`` (given in ``a``'s frame) into ``a``'s parent frame; rotation vectors are axis * angle
(rad); Euler angles ``(rx, ry, rz)`` mean ``R = Rx Ry Rz`` (the floating wrist's hinge order). Engines with
another quaternion order convert at their boundary with :func:`wxyz_to_xyzw` / :func:`xyzw_to_wxyz`.

Two matrix forms exist on purpose: :func:`quat_to_matrix` normalises its input first (any non-zero quaternion
is a rotation), :func:`unit_quat_to_matrix` is the quadratic form that equals :func:`quat_rotate`'s rotation for
any quaternion and is exact for unit ones (the environment's per-step path; both agree to ~1e-16 on unit input).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "GIMBAL_LOCK_COS",
    "bilinear_matrix",
    "compose",
    "euler_xyz_to_quat",
    "interpolate_pose",
    "matrix_to_pose",
    "matrix_to_quat",
    "outer16",
    "pose_to_matrix",
    "quat_conj",
    "quat_from_z_axis",
    "quat_mul",
    "quat_to_euler_xyz",
    "quat_to_matrix",
    "quat_to_rotvec",
    "relative",
    "rotation_between_frames",
    "rotvec_to_quat",
    "unit_quat_to_matrix",
    "wxyz_to_xyzw",
    "xyzw_to_wxyz",
]


def bilinear_matrix(terms: dict[tuple[int, int], dict[int, float]], out: int) -> np.ndarray:
    """(16, out) matrix M with ``outer16(a, b) @ M`` = Σ coef · a_i b_j per output k, from (i, j) -> {k: coef}.

    A bilinear form of two quaternions as one outer product times a constant matrix: three numpy calls
    instead of ~30 elementwise ones (on a few quaternions each call costs microseconds of dispatch)."""
    m = np.zeros((16, out))
    for (i, j), row in terms.items():
        for k, coef in row.items():
            m[4 * i + j, k] += coef
    return m


def outer16(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 16) flattened outer products of (..., 4) and (..., 4)."""
    outer = a[..., :, None] * b[..., None, :]
    return outer.reshape(*outer.shape[:-2], 16)


_W, _X, _Y, _Z = range(4)
_FEW_ROWS = 8
"""Up to this many (M, 4) rows :func:`quat_to_euler_xyz` computes on Python floats (a numpy call on a tiny array
costs ~1 µs of overhead)."""
_HAMILTON = bilinear_matrix(
    {
        (_W, _W): {0: 1.0}, (_X, _X): {0: -1.0}, (_Y, _Y): {0: -1.0}, (_Z, _Z): {0: -1.0},
        (_W, _X): {1: 1.0}, (_X, _W): {1: 1.0}, (_Y, _Z): {1: 1.0}, (_Z, _Y): {1: -1.0},
        (_W, _Y): {2: 1.0}, (_X, _Z): {2: -1.0}, (_Y, _W): {2: 1.0}, (_Z, _X): {2: 1.0},
        (_W, _Z): {3: 1.0}, (_X, _Y): {3: 1.0}, (_Y, _X): {3: -1.0}, (_Z, _W): {3: 1.0},
    },
    4,
)  # fmt: skip
"""The Hamilton product a * b as a bilinear form."""


def quat_mul(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Hamilton product ``a * b`` of (..., 4) wxyz quaternions (rotation b first, then a), float64;
    ``out``: where to write it."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return np.matmul(outer16(a, b), _HAMILTON, out=out)


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz -> (..., 3, 3) rotation matrices (input normalized first)."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) wxyz with w >= 0."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(rot, dtype=np.float64)
    xyzw = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    return wxyz.reshape(r.shape[:-2] + (4,))


def matrix_columns(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 6) their first two columns, first column first: a rotation's
    continuous 6-number form (Zhou et al., CVPR 2019), inverted by :func:`columns_to_matrix`."""
    r = np.asarray(rot, dtype=np.float64)
    return np.concatenate([r[..., :, 0], r[..., :, 1]], axis=-1)


def columns_to_matrix(cols: np.ndarray) -> np.ndarray:
    """(..., 6) two 3-vectors, as :func:`matrix_columns` gives -> (..., 3, 3) the rotation whose first column is the
    first vector's direction and whose second lies in the pair's plane (Gram-Schmidt; not the nearest rotation in
    the SVD sense, which would also turn the first column), the third column their cross product. Rows whose two
    vectors are zero, parallel or not finite define no rotation and come out NaN (as a blown-up env's observation
    reads)."""
    c = np.asarray(cols, dtype=np.float64)
    a, b = c[..., :3], c[..., 3:6]
    with np.errstate(all="ignore"):
        na = np.linalg.norm(a, axis=-1, keepdims=True)
        b = b - np.sum(a * b, axis=-1, keepdims=True) / (na * na) * a
        nb = np.linalg.norm(b, axis=-1, keepdims=True)
        undefined = ~((na > 1e-9) & (nb > 1e-9))  # NaN compares False: undefined too
        a, b = a / np.where(undefined, np.nan, na), b / np.where(undefined, np.nan, nb)
        return np.stack([a, b, np.cross(a, b)], axis=-1)


def pose_to_matrix(pose: np.ndarray) -> np.ndarray:
    """(..., 7) -> (..., 4, 4) homogeneous transforms."""
    p = np.asarray(pose, dtype=np.float64)
    out = np.zeros(p.shape[:-1] + (4, 4))
    out[..., :3, :3] = quat_to_matrix(p[..., 3:])
    out[..., :3, 3] = p[..., :3]
    out[..., 3, 3] = 1.0
    return out


def matrix_to_pose(mat: np.ndarray) -> np.ndarray:
    """(..., 4, 4) homogeneous transforms -> (..., 7)."""
    m = np.asarray(mat, dtype=np.float64)
    return np.concatenate([m[..., :3, 3], matrix_to_quat(m[..., :3, :3])], axis=-1)


def rotation_between_frames(a1: np.ndarray, a2: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """(3, 3) rotation R with R a1 = b1 exactly and R a2 as close to b2 as possible (a1 ⟂ a2 part kept)."""

    def basis(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        u = u / np.linalg.norm(u)
        v = v - (v @ u) * u
        v = v / np.linalg.norm(v)
        return np.stack([u, v, np.cross(u, v)], axis=1)

    return basis(np.asarray(b1, float), np.asarray(b2, float)) @ basis(np.asarray(a1, float), np.asarray(a2, float)).T


_ROTATION = bilinear_matrix(
    {
        (_Y, _Y): {0: -2.0, 8: -2.0}, (_Z, _Z): {0: -2.0, 4: -2.0}, (_X, _X): {4: -2.0, 8: -2.0},
        (_X, _Y): {1: 2.0, 3: 2.0}, (_W, _Z): {1: -2.0, 3: 2.0},
        (_X, _Z): {2: 2.0, 6: 2.0}, (_W, _Y): {2: 2.0, 6: -2.0},
        (_Y, _Z): {5: 2.0, 7: 2.0}, (_W, _X): {5: -2.0, 7: 2.0},
    },
    9,
)  # fmt: skip
"""Row-major R(q) - I as a quadratic form in q: ``R = I + 2 [[-(y²+z²), xy - wz, xz + wy], ...]``.

This form (not the homogeneous ``w² + x² - y² - z²`` one) equals :func:`ges_core.transforms_torch.quat_rotate`'s
``v + 2w (u × v) + 2u × (u × v)`` for any quaternion, unit or not."""

_EYE9 = np.eye(3).reshape(9)
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions), (..., 4) wxyz."""
    return q * _CONJ


def unit_quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz -> (..., 3, 3) rotation matrices R.

    ``R @ v`` is :func:`ges_core.transforms_torch.quat_rotate` (q, v); ``v @ R`` (v as a row) rotates by the inverse.
    """
    flat = outer16(q, q) @ _ROTATION + _EYE9
    return flat.reshape(*q.shape[:-1], 3, 3)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit wxyz -> (..., 3) rotation vector, angle in [0, pi].

    q and -q are one rotation: the angle comes from |w| and the sign of w flips the vector, as flipping q
    does (``w + 0.0`` turns -0.0 into +0.0, which the torch twin does not flip either). ``angle / s`` tends
    to ``2 / |w|`` as s -> 0 and atan2 keeps full precision there, so one formula serves every s (the torch
    helper switches to ``2 / w`` below 1e-9; the two differ by ~1e-18 relative); s = 0 gives 0.
    """
    w, v = q[..., 0], q[..., 1:]
    s = np.sqrt(np.add.reduce(v * v, axis=-1))
    scale = 2.0 * np.arctan2(s, np.abs(w)) / np.maximum(s, 1e-300)
    return v * np.copysign(scale, w + 0.0)[..., None]


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vector -> (..., 4) unit wxyz.

    ``sin(x/2) / x`` keeps full precision for tiny x (the torch twin's series differs by ~1e-18 relative
    below 1e-9); x = 0 gives the identity.
    """
    angle = np.sqrt(np.add.reduce(r * r, axis=-1, keepdims=True))
    half = 0.5 * angle
    return np.concatenate([np.cos(half), r * (np.sin(half) / np.maximum(angle, 1e-300))], axis=-1)


def euler_xyz_to_quat(angles: np.ndarray) -> np.ndarray:
    """(..., 3) angles (rx, ry, rz) of ``R = Rx Ry Rz`` -> (..., 4) quaternion wxyz."""
    a = np.asarray(angles, dtype=np.float64) / 2
    cx, cy, cz = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sx, sy, sz = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    w = cx * cy * cz - sx * sy * sz
    x = sx * cy * cz + cx * sy * sz
    y = cx * sy * cz - sx * cy * sz
    z = cx * cy * sz + sx * sy * cz
    return np.stack([w, x, y, z], axis=-1)


def quat_to_euler_xyz(quat: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions wxyz (normalised first) -> (..., 3) angles (rx, ry, rz) with ``R = Rx Ry Rz``.

    At gimbal lock (ry = +-pi/2, where only rx + rz or rx - rz is defined) rz is 0 and rx carries the whole turn about
    the shared axis, as scipy's ``as_euler("XYZ")`` does; the lock is taken where ``cos(ry)`` is below
    ``GIMBAL_LOCK_COS`` (1e-8), the point from which the general formulas, whose rx and rz are then arctangents of
    rounding noise, lose more than the lock's ``rz = 0`` does (both below 1e-5 degrees there; at ``cos(ry)`` 1e-13
    the general formulas are 0.7 degrees off, at exact lock up to 180). Without it a base pose at the lock reached
    the wrist turned by up to 180 degrees about the shared axis (the Inspire hand's palm-down start: 90 degrees).

    For up to ``_FEW_ROWS`` rows of shape (M, 4) the same float64 operations run in the same order on
    Python floats (IEEE arithmetic, correctly rounded square root) and only arcsin and arctan2 go to numpy,
    whose results do not depend on the array's length: bit for bit the numpy path, about 8 µs instead of
    24 µs for one pose (a wrist command per env step is the common case; ``tests/test_transforms.py`` checks
    the bits). The lock's two extra matrix entries are computed for rows at the lock only.
    """
    quat = np.asarray(quat, dtype=np.float64)
    if quat.ndim != 2 or len(quat) > _FEW_ROWS:
        return _euler_xyz_numpy(quat)
    r02, r12, r22, r01, r00 = [], [], [], [], []
    locked: dict[int, tuple[float, float]] = {}  # row -> (r21, r11), read at gimbal lock only
    for row, (w, x, y, z) in enumerate(quat.tolist()):
        n = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        r02.append(min(max(2 * (x * z + w * y), -1.0), 1.0))
        r12.append(-(2 * (y * z - w * x)))
        r22.append(1 - 2 * (x * x + y * y))
        r01.append(-(2 * (x * y - w * z)))
        r00.append(1 - 2 * (y * y + z * z))
        if r12[-1] * r12[-1] + r22[-1] * r22[-1] < _GIMBAL_LOCK_COS2:
            locked[row] = (2 * (y * z + w * x), 1 - 2 * (x * x + z * z))
    rx, rz = np.arctan2(r12, r22), np.arctan2(r01, r00)
    if locked:
        rows = list(locked)
        r21, r11 = zip(*locked.values(), strict=True)
        rx[rows], rz[rows] = np.arctan2(r21, r11), 0.0
    return np.stack([rx, np.arcsin(r02), rz], axis=-1).reshape(len(quat), 3)


GIMBAL_LOCK_COS = 1e-8
"""``cos(ry)`` below which :func:`quat_to_euler_xyz` takes gimbal lock (docstring there)."""
_GIMBAL_LOCK_COS2 = GIMBAL_LOCK_COS * GIMBAL_LOCK_COS


def _euler_xyz_numpy(quat: np.ndarray) -> np.ndarray:
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r02 = 2 * (x * z + w * y)
    r12 = 2 * (y * z - w * x)
    r22 = 1 - 2 * (x * x + y * y)
    r01 = 2 * (x * y - w * z)
    r00 = 1 - 2 * (y * y + z * z)
    ry = np.arcsin(np.clip(r02, -1.0, 1.0))
    rx, rz = np.arctan2(-r12, r22), np.arctan2(-r01, r00)
    lock = r12 * r12 + r22 * r22 < _GIMBAL_LOCK_COS2
    if lock.any():
        r21, r11 = 2 * (y * z + w * x), 1 - 2 * (x * x + z * z)
        rx, rz = np.where(lock, np.arctan2(r21, r11), rx), np.where(lock, 0.0, rz)
    return np.stack([rx, ry, rz], axis=-1)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(7,) pose ``a * b``: ``b`` given in ``a``'s frame, returned in ``a``'s parent frame."""
    return matrix_to_pose(pose_to_matrix(a) @ pose_to_matrix(b))


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(7,) pose of ``b`` in the frame ``a`` (both (7,) in one parent frame): ``a^-1 * b``."""
    return matrix_to_pose(np.linalg.inv(pose_to_matrix(a)) @ pose_to_matrix(b))


def interpolate_pose(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """(7,) pose ``t`` of the way from ``a`` to ``b``: linear position, spherical (slerp) rotation.

    One pose, the arccos form of slerp; the torch twin (:func:`ges_core.transforms_torch.interpolate_pose`,
    batched) takes the rotation-vector form of the same rotation (they agree to ~1e-15).
    """
    qa, qb = a[3:] / np.linalg.norm(a[3:]), b[3:] / np.linalg.norm(b[3:])
    dot = float(qa @ qb)
    if dot < 0.0:  # the shorter way round
        qb, dot = -qb, -dot
    angle = np.arccos(min(1.0, dot))
    if angle < 1e-6:
        quat = qa + t * (qb - qa)
    else:
        quat = (np.sin((1 - t) * angle) * qa + np.sin(t * angle) * qb) / np.sin(angle)
    return np.concatenate([a[:3] + t * (b[:3] - a[:3]), quat / np.linalg.norm(quat)])


def wxyz_to_xyzw(quat: np.ndarray) -> np.ndarray:
    """(..., 4) w, x, y, z -> (..., 4) x, y, z, w (PyBullet's order)."""
    q = np.asarray(quat, dtype=np.float64)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def xyzw_to_wxyz(quat: np.ndarray) -> np.ndarray:
    """(..., 4) x, y, z, w -> (..., 4) w, x, y, z."""
    q = np.asarray(quat, dtype=np.float64)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def quat_from_z_axis(direction: np.ndarray) -> list[float]:
    """The quaternion (w, x, y, z, Python floats) of the shortest rotation taking +z onto ``direction`` (3,)."""
    z = np.array([0.0, 0.0, 1.0])
    d = direction / np.linalg.norm(direction)
    axis, c = np.cross(z, d), float(z @ d)
    if np.linalg.norm(axis) < 1e-9:
        return [1.0, 0.0, 0.0, 0.0] if c > 0 else [0.0, 1.0, 0.0, 0.0]
    axis = axis / np.linalg.norm(axis)
    half = math.acos(max(-1.0, min(1.0, c))) / 2
    return [math.cos(half), *(axis * math.sin(half)).tolist()]
