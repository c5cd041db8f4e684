"""Pose conversions. Poses are (..., 7): position (m) then unit quaternion w, x, y, z."""

from __future__ import annotations

import numpy as np

__all__ = [
    "matrix_to_pose",
    "matrix_to_quat",
    "pose_to_matrix",
    "quat_mul",
    "quat_to_matrix",
    "rotation_between_frames",
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
