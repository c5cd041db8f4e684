"""The torch twin of :mod:`ges_core.transforms`: the same conventions, batched over leading dimensions.

Quaternions are **w, x, y, z**; poses ``(..., 7)`` position (m) then quaternion; rotation vectors are axis *
angle (rad). The numpy functions of the same names in :mod:`ges_core.transforms` compute the same values
(``tests/test_transforms.py`` checks each pair); use these where the data is already in tensors (experts,
policies), the numpy ones on the environment's per-step path, where torch's per-op dispatch costs more than
the maths on a few envs.
"""

from __future__ import annotations

import torch

__all__ = ["interpolate_pose", "quat_conj", "quat_mul", "quat_rotate", "quat_to_rotvec", "rotvec_to_quat"]


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
