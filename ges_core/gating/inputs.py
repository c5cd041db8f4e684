"""What every gate does to its input before looking at it: check it and bring it to the gate's size."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ges_core.errors import ArrayError
from ges_core.gating.clouds import fit_cloud, stack_clouds

__all__ = ["gate_input"]


def gate_input(
    points: torch.Tensor | Sequence[np.ndarray], n_points: int, object_ids: Sequence[str] | None = None
) -> torch.Tensor:
    """(n, n_points, 3) float32 clouds, object frame, metres, checked.

    points: a (n, N, 3) tensor or a list of (m_i, 3) arrays. Clouds of another size are brought to
    ``n_points`` (:func:`ges_core.gating.clouds.fit_cloud`: farthest points, or repeated points with a
    warning); an empty, NaN or misshapen cloud is an ArrayError naming the object (``object_ids[i]``, or
    its index in the batch).
    """
    if isinstance(points, torch.Tensor):
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ArrayError(f"gate input has shape {tuple(points.shape)}, expected (objects, points, 3)")
        ids = _ids(object_ids, points.shape[0])
        if points.shape[1] == n_points:
            _check_finite(points, ids)
            return points.detach().float()
        return stack_clouds([p.detach().cpu().numpy() for p in points], n_points, ids)
    ids = _ids(object_ids, len(points))
    return torch.from_numpy(np.stack([fit_cloud(c, n_points, i) for c, i in zip(points, ids, strict=True)]))


def _ids(object_ids: Sequence[str] | None, n: int) -> list[str]:
    if object_ids is None:
        return [f"#{i} of the batch" for i in range(n)]
    if len(object_ids) != n:
        raise ArrayError(f"{n} clouds but {len(object_ids)} object ids")
    return list(object_ids)


def _check_finite(points: torch.Tensor, ids: list[str]) -> None:
    bad = ~torch.isfinite(points).all(dim=-1)
    if bad.any():
        i = int(bad.any(dim=1).nonzero()[0])
        raise ArrayError(
            f"object '{ids[i]}': {int(bad[i].sum())} of {points.shape[1]} points are NaN or infinite "
            f"({int(bad.any(dim=1).sum())} bad clouds in the batch); check the mesh or sensor that produced them"
        )
