"""Local optimization of five contacts for force closure and five-finger coordination.

Coordinate descent over nearby surface points. Each contact may move to an eligible cloud point
within ``radius`` of its extremum pick; a move is scored by

    J = || sum_i w_i W(p_i, n_i) ||^2  +  kappa * sum_i || p_i - p_i^0 ||^2 / spacing^2

where ``W(p, n) = [-n, (p - c) x (-n) / r]`` is the wrench of a unit inward normal force about the
object centre ``c`` (``r`` the object radius) and the weights give the thumb the force of the four
fingers together (``w = [4, 1, 1, 1, 1] / 8``): the first term is zero when the normal forces of
that thumb-against-fingers squeeze balance (force and torque), the second keeps each contact near
its place in the layout (the coordination term); thumb and index move at most ``radius / 2`` (the
pinch). The net-wrench term is the cheap, smooth proxy of force closure used by DexGraspNet's
energy; epsilon itself is only evaluated on the result.
"""

from __future__ import annotations

import numpy as np

__all__ = ["optimize_contacts", "unit_wrenches"]

SLOT_WEIGHTS = np.array([4.0, 1.0, 1.0, 1.0, 1.0]) / 8.0
"""Thumb opposes the four fingers: its normal force equals theirs together."""
PINCH_RADIUS = np.array([0.5, 0.5, 1.0, 1.0, 1.0])
"""Move radius per slot relative to ``radius``: thumb and index move half as far, so the optimization
cannot trade the thumb-index pinch for balance (it otherwise drifts the thumb toward the middle finger)."""
MAX_POOL = 48
"""Candidate points per contact (nearest first); bounds the cost per sweep."""


def unit_wrenches(points: np.ndarray, normals: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """(..., 6) wrench of a unit inward normal force at each point about ``center``, torque / ``radius``."""
    f = -normals
    return np.concatenate([f, np.cross(points - center, f) / radius], axis=-1)


def candidate_pools(points: np.ndarray, start: np.ndarray, allowed: np.ndarray, radius: np.ndarray) -> list[np.ndarray]:
    """For each contact, indices of the allowed points within ``radius[i]`` of its start (nearest first)."""
    d2 = ((points[None, :, :] - points[start][:, None, :]) ** 2).sum(axis=2)  # (5, n)
    pools = []
    for i in range(len(start)):
        idx = np.flatnonzero(allowed[i] & (d2[i] <= radius[i] ** 2))
        idx = idx[np.argsort(d2[i, idx], kind="stable")][:MAX_POOL]
        pools.append(idx if len(idx) else start[i : i + 1])
    return pools


def optimize_contacts(
    points: np.ndarray,
    normals: np.ndarray,
    start: np.ndarray,
    allowed: np.ndarray,
    *,
    center: np.ndarray,
    object_radius: float,
    spacing: float,
    radius: float,
    kappa: float,
    sweeps: int,
) -> np.ndarray:
    """Indices (5,) of the optimized contacts, starting from ``start`` (5,); see the module docstring.

    points, normals: (n, 3) resting frame; allowed: (5, n) bool eligibility per contact.
    """
    pools = candidate_pools(points, start, allowed, radius * PINCH_RADIUS)
    wrench = unit_wrenches(points, normals, center, object_radius)  # (n, 6)
    anchor = points[start]
    cur = start.copy()
    for _ in range(sweeps):
        moved = False
        for i, pool in enumerate(pools):
            rest = (SLOT_WEIGHTS[:, None] * wrench[cur]).sum(axis=0) - SLOT_WEIGHTS[i] * wrench[cur[i]]
            net = rest[None, :] + SLOT_WEIGHTS[i] * wrench[pool]
            drift = ((points[pool] - anchor[i]) ** 2).sum(axis=1) / spacing**2
            best = pool[int(np.argmin((net**2).sum(axis=1) + kappa * drift))]
            moved |= bool(best != cur[i])
            cur[i] = best
        if not moved:
            break
    return cur
