"""Batched point-cloud operations shared by the gate backbones (torch, any device).

Every choice here depends on the points' positions only, never on their order in the tensor, so a
backbone built from these operations gives the same answer for any permutation of its input points
(up to floating-point rounding and exact distance ties): farthest-point sampling starts at the point
farthest from the centroid, and neighbourhoods are the nearest points, not the first ones in memory.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = [
    "ball_from_neighbours",
    "ball_query",
    "farthest_point_sample",
    "gather_points",
    "knn",
    "max_over_neighbours",
    "square_distance",
]


def square_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distances (B, N, M) between a: (B, N, 3) and b: (B, M, 3) (same unit as the inputs)."""
    d = -2.0 * a @ b.transpose(1, 2)
    d = d + (a * a).sum(-1, keepdim=True) + (b * b).sum(-1).unsqueeze(1)
    return d.clamp_min(0.0)


def gather_points(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Rows of values: (B, N, C) at idx: (B, ...) int64 -> (B, ..., C).

    One ``index_select`` on the (B N, C) rows (idx offset by N per cloud): 3-6x faster than
    ``torch.gather`` with an index expanded over the channels (12 neighbours of 1024 points, 3 -> 64
    channels: 126 -> 34 us to 2.3 -> 0.40 ms, one thread).
    """
    batch, n, channels = values.shape
    flat = idx.reshape(batch, -1)
    if batch > 1:
        flat = flat + (torch.arange(batch, device=idx.device) * n).unsqueeze(1)
    rows = values.reshape(batch * n, channels).index_select(0, flat.reshape(-1))
    return rows.view(*idx.shape, channels)


def max_over_neighbours(x: torch.Tensor) -> torch.Tensor:
    """(B, M, k, C) -> (B, M, C): the maximum over the k neighbours (dim 2).

    Below :data:`MAX_CHAIN_CHANNELS` channels as k - 1 element-wise maxima of (B, M, C) slices: torch's
    reduction over a middle dim with a short inner stride is slow on the CPU (1024 x 12 x 16, one thread:
    ``amax`` 180 us, ``max(...).values`` 590 us, the chain 60 us); from that width on ``amax`` is faster
    (1024 x 12 x 32: 80 against 120 us; 512 x 32 x 64: 280 against 480 us).
    """
    if x.shape[-1] >= MAX_CHAIN_CHANNELS:
        return x.amax(dim=2)
    out = x[:, :, 0]
    for j in range(1, x.shape[2]):
        out = torch.maximum(out, x[:, :, j])
    return out


MAX_CHAIN_CHANNELS = 32
"""From this many channels on, :func:`max_over_neighbours` uses ``amax`` (measured above, one CPU thread)."""


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
    """:func:`farthest_point_sample` of one (N, 3) cloud, the same steps in the same precision (the squared
    distance summed as (dx^2 + dy^2) + dz^2 there too). Coordinates as rows of a (3, N) array, so a step is
    five ufunc calls on it, written into preallocated arrays (1.2 against 1.7 ms for 256 of 1024 points
    with three separate coordinate arrays)."""
    rows = np.ascontiguousarray(points.T)  # (3, N)
    centre = points.mean(axis=0)
    step = np.empty_like(rows)
    np.subtract(rows, centre[:, None], out=step)
    current = np.add.reduce(np.square(step, out=step), axis=0).argmax()
    dist = np.full(len(points), np.inf, dtype=points.dtype)
    near = np.empty_like(dist)
    chosen = [0] * m
    # bound ufuncs and methods, a (3, 1) column view per point and the reduction written into ``near``:
    # 1.17 -> 1.02 ms for 256 of 1024 points (the same operations, fewer lookups and allocations)
    sub, square, add, minimum, argmax = np.subtract, np.square, np.add.reduce, np.minimum, dist.argmax
    columns = rows.T[:, :, None]  # (N, 3, 1)
    for i in range(m):
        chosen[i] = current
        sub(rows, columns[current], out=step)
        add(square(step, out=step), axis=0, out=near)
        minimum(dist, near, out=dist)
        current = argmax()
    return np.array(chosen, dtype=np.int64)


def knn(xyz: torch.Tensor, k: int, query: torch.Tensor | None = None) -> torch.Tensor:
    """Indices (B, M, k) int64 of the k nearest points of xyz: (B, N, 3) to each query (B, M, 3), nearest
    first (query defaults to xyz itself, whose nearest neighbour is then the point itself)."""
    return _nearest(xyz, xyz if query is None else query, min(k, xyz.shape[1]), distances=False)[1]


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, k: int) -> torch.Tensor:
    """Indices (B, M, k) int64 of up to k nearest points of xyz: (B, N, 3) within ``radius`` of each centre
    (B, M, 3); a ball with fewer repeats its nearest point (a centre drawn from xyz has at least itself)."""
    near_d, near = _nearest(xyz, centres, min(k, xyz.shape[1]))
    outside = near_d > radius * radius
    return torch.where(outside, near[..., :1].expand_as(near), near)


def ball_from_neighbours(
    xyz: torch.Tensor, centre_idx: torch.Tensor, neighbours: torch.Tensor, radius: float, k: int
) -> torch.Tensor:
    """:func:`ball_query` for centres drawn from xyz, read off a kNN of xyz that is already known.

    xyz: (B, N, 3); centre_idx: (B, M) indices of the centres in xyz; neighbours: (B, N, k') nearest points
    of every point, nearest first (``knn(xyz, k')``), k' >= k. Returns (B, M, k) int64: the same balls as
    ``ball_query(xyz, gather_points(xyz, centre_idx), radius, k)`` (up to exact distance ties) without a
    second search: the k nearest of a centre are the first k of its own row.
    """
    if neighbours.shape[-1] < min(k, xyz.shape[1]):
        raise ValueError(f"ball_from_neighbours: {neighbours.shape[-1]} neighbours known, {k} asked")
    near = gather_points(neighbours[..., :k], centre_idx)  # (B, M, k)
    centres = gather_points(xyz, centre_idx)
    outside = ((gather_points(xyz, near) - centres.unsqueeze(2)) ** 2).sum(-1) > radius * radius
    return torch.where(outside, near[..., :1].expand_as(near), near)


def _nearest(
    xyz: torch.Tensor, query: torch.Tensor, k: int, *, distances: bool = True
) -> tuple[torch.Tensor | None, torch.Tensor]:
    """Squared distances (None unless ``distances``) and indices (B, M, k) of the k nearest points of xyz to
    each query, nearest first.

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
    m = qs.shape[1]
    idx = torch.from_numpy(np.stack([f[1] for f in found]).reshape(len(qs), m, k).astype(np.int64, copy=False))
    if not distances:
        return None, idx
    dist = np.stack([f[0] for f in found]).reshape(len(qs), m, k)
    return torch.from_numpy(dist**2).to(xyz.dtype), idx
