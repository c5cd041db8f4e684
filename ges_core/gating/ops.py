"""Batched point-cloud operations shared by the gate backbones (torch, any device).

Every choice here depends on the points' positions only, never on their order in the tensor, so a
backbone built from these operations gives the same answer for any permutation of its input points
(up to floating-point rounding and exact distance ties): farthest-point sampling starts at the point
farthest from the centroid, and neighbourhoods are the nearest points, not the first ones in memory.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["ball_query", "farthest_point_sample", "gather_points", "knn", "square_distance"]


def square_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distances (B, N, M) between a: (B, N, 3) and b: (B, M, 3) (same unit as the inputs)."""
    d = -2.0 * a @ b.transpose(1, 2)
    d = d + (a * a).sum(-1, keepdim=True) + (b * b).sum(-1).unsqueeze(1)
    return d.clamp_min(0.0)


def gather_points(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Rows of values: (B, N, C) at idx: (B, ...) int64 -> (B, ..., C)."""
    batch = values.shape[0]
    flat = idx.reshape(batch, -1)
    out = torch.gather(values, 1, flat.unsqueeze(-1).expand(-1, -1, values.shape[-1]))
    return out.reshape(*idx.shape, values.shape[-1])


def farthest_point_sample(xyz: torch.Tensor, m: int) -> torch.Tensor:
    """Indices (B, m) int64 of a greedy farthest-point subset of xyz: (B, N, 3).

    Starts at the point farthest from the cloud's centroid (order-independent, unlike index 0).
    m >= N returns every index. A few CPU clouds go through numpy (1.7 against 7.4 ms for 256 of 1024
    points: the loop is all per-step overhead), a batch through torch (one step serves every cloud).
    """
    batch, n, _ = xyz.shape
    if m >= n:
        return torch.arange(n, device=xyz.device).expand(batch, n)
    if xyz.device.type == "cpu" and batch <= NUMPY_FPS_MAX_BATCH:
        return torch.from_numpy(np.stack([_fps_numpy(c, m) for c in xyz.detach().numpy()]))
    rows = torch.arange(batch, device=xyz.device)
    chosen = torch.empty(batch, m, dtype=torch.long, device=xyz.device)
    centre = xyz.mean(dim=1, keepdim=True)
    current = ((xyz - centre) ** 2).sum(-1).argmax(dim=1)
    dist = torch.full((batch, n), float("inf"), dtype=xyz.dtype, device=xyz.device)
    for i in range(m):
        chosen[:, i] = current
        step = ((xyz - xyz[rows, current].unsqueeze(1)) ** 2).sum(-1)
        dist = torch.minimum(dist, step)
        current = dist.argmax(dim=1)
    return chosen


NUMPY_FPS_MAX_BATCH = 4
"""Up to this many clouds, :func:`farthest_point_sample` loops over them in numpy (faster below ~5)."""


def _fps_numpy(points: np.ndarray, m: int) -> np.ndarray:
    """:func:`farthest_point_sample` of one (N, 3) cloud, the same steps in the same precision."""
    x, y, z = (np.ascontiguousarray(points[:, i]) for i in range(3))
    centre = points.mean(axis=0)
    current = int((((x - centre[0]) ** 2 + (y - centre[1]) ** 2) + (z - centre[2]) ** 2).argmax())
    dist = np.full(len(points), np.inf, dtype=points.dtype)
    chosen = np.empty(m, dtype=np.int64)
    for i in range(m):
        chosen[i] = current
        dx, dy, dz = x - x[current], y - y[current], z - z[current]
        np.minimum(dist, (dx * dx + dy * dy) + dz * dz, out=dist)
        current = int(dist.argmax())
    return chosen


def knn(xyz: torch.Tensor, k: int, query: torch.Tensor | None = None) -> torch.Tensor:
    """Indices (B, M, k) int64 of the k nearest points of xyz: (B, N, 3) to each query (B, M, 3), nearest
    first (query defaults to xyz itself, whose nearest neighbour is then the point itself)."""
    return _nearest(xyz, xyz if query is None else query, min(k, xyz.shape[1]))[1]


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, k: int) -> torch.Tensor:
    """Indices (B, M, k) int64 of up to k nearest points of xyz: (B, N, 3) within ``radius`` of each centre
    (B, M, 3); a ball with fewer repeats its nearest point (a centre drawn from xyz has at least itself)."""
    near_d, near = _nearest(xyz, centres, min(k, xyz.shape[1]))
    outside = near_d > radius * radius
    return torch.where(outside, near[..., :1].expand_as(near), near)


def _nearest(xyz: torch.Tensor, query: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared distances and indices (B, M, k) of the k nearest points of xyz to each query, nearest first.

    On the CPU a k-d tree per cloud (scipy): 2.3 ms instead of 14.8 ms for k = 17 of 1024 points, the
    largest single cost of CurveNet's inference (benchmarks/gate_speed.py); elsewhere a full distance
    matrix and topk. Indices carry no gradient either way.
    """
    if xyz.device.type != "cpu":
        d, idx = square_distance(query, xyz).topk(k, dim=-1, largest=False)
        return d, idx
    from scipy.spatial import cKDTree

    pts, qs = xyz.detach().numpy(), query.detach().numpy()
    found = [cKDTree(p).query(q, k) for p, q in zip(pts, qs, strict=True)]
    dist = np.stack([f[0].reshape(len(q), k) for f, q in zip(found, qs, strict=True)])
    idx = np.stack([f[1].reshape(len(q), k) for f, q in zip(found, qs, strict=True)])
    return torch.from_numpy(dist**2).to(xyz.dtype), torch.from_numpy(idx.astype(np.int64))
