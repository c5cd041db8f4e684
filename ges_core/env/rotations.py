"""Batched torch rotation helpers. Quaternions are **w, x, y, z**; rotation vectors are axis * angle (rad)."""

from __future__ import annotations

import torch

__all__ = ["quat_mul", "quat_conj", "quat_to_rotvec", "rotvec_to_quat", "quat_rotate"]


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
