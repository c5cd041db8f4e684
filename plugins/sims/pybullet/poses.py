"""Quaternion and pose arithmetic at PyBullet's boundary.

GES-UniGrasp poses are ``(..., 7)``: position (m) then a unit quaternion **w, x, y, z**.
PyBullet speaks **x, y, z, w**; every conversion between the two happens here, so the backend
never hands a raw PyBullet quaternion to its caller.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "IDENTITY_POSE",
    "to_pybullet",
    "from_pybullet",
    "wxyz_to_xyzw",
    "xyzw_to_wxyz",
]

IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
"""(7,) the identity pose, wxyz."""


def wxyz_to_xyzw(quat: np.ndarray) -> np.ndarray:
    """(..., 4) w, x, y, z -> (..., 4) x, y, z, w."""
    q = np.asarray(quat, dtype=np.float64)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def xyzw_to_wxyz(quat: np.ndarray) -> np.ndarray:
    """(..., 4) x, y, z, w -> (..., 4) w, x, y, z."""
    q = np.asarray(quat, dtype=np.float64)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def to_pybullet(pose: np.ndarray) -> tuple[list[float], list[float]]:
    """(7,) wxyz pose -> PyBullet ``(position, orientation xyzw)`` lists."""
    pose = np.asarray(pose, dtype=np.float64)
    return pose[:3].tolist(), wxyz_to_xyzw(pose[3:]).tolist()


def from_pybullet(position: object, orientation: object) -> np.ndarray:
    """PyBullet ``(position, orientation xyzw)`` -> (7,) wxyz pose."""
    xyzw = np.asarray(orientation, dtype=np.float64)
    return np.concatenate([np.asarray(position, dtype=np.float64), xyzw[3:], xyzw[:3]])
