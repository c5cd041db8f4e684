"""Quaternion and pose arithmetic at PyBullet's boundary.

GES-UniGrasp poses are ``(..., 7)``: position (m) then a unit quaternion **w, x, y, z**.
PyBullet speaks **x, y, z, w**; every conversion between the two happens here, so the backend
never hands a raw PyBullet quaternion to its caller (the order swaps themselves are
:mod:`ges_core.transforms`'s).
"""

from __future__ import annotations

import numpy as np

from ges_core.transforms import wxyz_to_xyzw

__all__ = ["from_pybullet", "to_pybullet"]


def to_pybullet(pose: np.ndarray) -> tuple[list[float], list[float]]:
    """(7,) wxyz pose -> PyBullet ``(position, orientation xyzw)`` lists."""
    pose = np.asarray(pose, dtype=np.float64)
    return pose[:3].tolist(), wxyz_to_xyzw(pose[3:]).tolist()


def from_pybullet(position: object, orientation: object) -> np.ndarray:
    """PyBullet ``(position, orientation xyzw)`` -> (7,) wxyz pose."""
    xyzw = np.asarray(orientation, dtype=np.float64)
    return np.concatenate([np.asarray(position, dtype=np.float64), xyzw[3:], xyzw[:3]])
