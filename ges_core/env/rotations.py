"""Batched rotation helpers, torch and (suffix ``_np``) numpy float64. Quaternions are **w, x, y, z**; rotation
vectors are axis * angle (rad).
"""

from __future__ import annotations

import numpy as np
import torch

from ges_core.transforms import bilinear_matrix, outer16
from ges_core.transforms import quat_mul as quat_mul_np  # the numpy Hamilton product (one implementation)

__all__ = [
    "interpolate_pose",
    "quat_conj",
    "quat_conj_np",
    "quat_mul",
    "quat_mul_np",
    "quat_rotate",
    "quat_to_matrix_np",
    "quat_to_rotvec",
    "quat_to_rotvec_np",
    "rotvec_to_quat",
    "rotvec_to_quat_np",
]


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b``, (..., 4) wxyz."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def quat_conj(q: torch.Tensor) -> torch.Tensor:
    """Conjugate (= inverse for unit quaternions), (..., 4) wxyz."""
    return q * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q.dtype, device=q.device)


def quat_to_rotvec(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit wxyz -> (..., 3) rotation vector, angle in [0, pi] (the shorter way round)."""
    q = q * torch.where(q[..., :1] < 0, -1.0, 1.0)  # q and -q are one rotation; w >= 0 gives angle <= pi
    v = q[..., 1:]
    s = v.norm(dim=-1, keepdim=True)
    angle = 2.0 * torch.atan2(s, q[..., :1])
    scale = torch.where(s > 1e-9, angle / s.clamp_min(1e-12), 2.0 / q[..., :1].clamp_min(1e-12))
    return v * scale


def rotvec_to_quat(r: torch.Tensor) -> torch.Tensor:
    """(..., 3) rotation vector -> (..., 4) unit wxyz."""
    angle = r.norm(dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(x/2)/x -> 1/2 as x -> 0
    k = torch.where(angle > 1e-9, torch.sin(half) / angle.clamp_min(1e-12), 0.5 - angle**2 / 48.0)
    return torch.cat([torch.cos(half), r * k], dim=-1)


def quat_rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4) wxyz (broadcasting)."""
    qv = q[..., 1:]
    t = 2.0 * torch.cross(qv.expand_as(v), v, dim=-1)
    return v + q[..., :1] * t + torch.cross(qv.expand_as(v), t, dim=-1)


def interpolate_pose(a: torch.Tensor, b: torch.Tensor, s: float | torch.Tensor) -> torch.Tensor:
    """(n, 7) poses a fraction ``s`` in [0, 1] (a number, or (n, 1) per pose) from ``a`` to ``b`` (n, 7):
    linear position, slerp rotation (wxyz)."""
    rel = quat_to_rotvec(quat_mul(b[:, 3:], quat_conj(a[:, 3:])))
    return torch.cat([a[:, :3] + s * (b[:, :3] - a[:, :3]), quat_mul(rotvec_to_quat(s * rel), a[:, 3:])], dim=1)


# -- numpy float64 versions for the environment's per-step path -----------------------------------
# The same maths as the torch helpers above on numpy arrays: on a handful of envs every torch op costs
# several microseconds of dispatch, so the per-control-step code (observation, wrist targets) uses these
# and converts to torch once. The quadratic form below is one outer product times a constant matrix
# (ges_core.transforms.bilinear_matrix), as is the Hamilton product quat_mul_np (ges_core.transforms.quat_mul).

_W, _X, _Y, _Z = range(4)
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

This form (not the homogeneous ``w² + x² - y² - z²`` one) equals :func:`quat_rotate`'s
``v + 2w (u × v) + 2u × (u × v)`` for any quaternion, unit or not."""

_EYE9 = np.eye(3).reshape(9)
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def quat_conj_np(q: np.ndarray) -> np.ndarray:
    """Conjugate, (..., 4) wxyz (numpy :func:`quat_conj`)."""
    return q * _CONJ


def quat_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz -> (..., 3, 3) rotation matrices R.

    ``R @ v`` is :func:`quat_rotate` (q, v); ``v @ R`` (v as a row) rotates by the inverse.
    """
    flat = outer16(q, q) @ _ROTATION + _EYE9
    return flat.reshape(*q.shape[:-1], 3, 3)


def quat_to_rotvec_np(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit wxyz -> (..., 3) rotation vector, angle in [0, pi] (numpy :func:`quat_to_rotvec`).

    q and -q are one rotation: the angle comes from |w| and the sign of w flips the vector, as flipping q
    does (``w + 0.0`` turns -0.0 into +0.0, which the torch helper does not flip either). ``angle / s`` tends
    to ``2 / |w|`` as s -> 0 and atan2 keeps full precision there, so one formula serves every s (the torch
    helper switches to ``2 / w`` below 1e-9; the two differ by ~1e-18 relative); s = 0 gives 0.
    """
    w, v = q[..., 0], q[..., 1:]
    s = np.sqrt(np.add.reduce(v * v, axis=-1))
    scale = 2.0 * np.arctan2(s, np.abs(w)) / np.maximum(s, 1e-300)
    return v * np.copysign(scale, w + 0.0)[..., None]


def rotvec_to_quat_np(r: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vector -> (..., 4) unit wxyz (numpy :func:`rotvec_to_quat`).

    ``sin(x/2) / x`` keeps full precision for tiny x (the torch helper's series differs by ~1e-18 relative
    below 1e-9); x = 0 gives the identity.
    """
    angle = np.sqrt(np.add.reduce(r * r, axis=-1, keepdims=True))
    half = 0.5 * angle
    return np.concatenate([np.cos(half), r * (np.sin(half) / np.maximum(angle, 1e-300))], axis=-1)
