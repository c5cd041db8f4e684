"""Object point clouds as a gate reads them: checked, brought to a fixed size, batched, augmented.

Frames and units: every cloud is in the object frame (the library's resting frame, z up, origin on
the base), metres. Gates see the metric size on purpose: which expert wins depends on it (the paper's
expert 1 takes small flat objects, expert 3 large boxes).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.errors import ArrayError
from ges_core.objects.pointcloud import farthest_point_indices

__all__ = [
    "AugmentConfig",
    "ResampledCloudWarning",
    "augment",
    "fit_cloud",
    "library_clouds",
    "stack_clouds",
]

log = logging.getLogger(__name__)


class ResampledCloudWarning(UserWarning):
    """A cloud had fewer points than the gate reads; points were repeated to fill it."""


class AugmentConfig(ConfigModel):
    """Training-time augmentation of the object clouds (each epoch draws new values, seeded)."""

    enabled: bool = Field(True, description="augment at all (False: the clouds as sampled)")
    rotate_z: bool = Field(True, description="rotate each cloud by a uniform angle about the object frame's z (up)")
    scale: float = Field(
        0.1,
        ge=0.0,
        lt=1.0,
        description="uniform scale factor drawn in [1 - scale, 1 + scale] (fraction); 0.1 keeps a cloud within "
        "the size band of its category while blurring exact sizes the gate could memorize",
    )


def fit_cloud(points: np.ndarray, n: int, object_id: str, *, seed: int = 0) -> np.ndarray:
    """``points`` (m, 3) brought to (n, 3) float32, object frame, metres.

    More points: the farthest-point subset. Fewer: every point kept and m - n of them repeated (seeded),
    with a :class:`ResampledCloudWarning` and a log line naming the object. Empty, NaN/infinite or
    misshapen clouds: ArrayError naming the object.
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[-1] != 3:
        raise ArrayError(f"object '{object_id}': point cloud has shape {arr.shape}, expected (points, 3)")
    if len(arr) == 0:
        raise ArrayError(
            f"object '{object_id}': point cloud is empty; sample its surface again (ObjectLibrary.point_cloud)"
        )
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise ArrayError(
            f"object '{object_id}': {int(bad.sum())} of {len(arr)} points are NaN or infinite; "
            f"check the mesh or the sensor that produced the cloud"
        )
    if len(arr) >= n:
        return arr[farthest_point_indices(arr, n)].astype(np.float32)
    extra = np.random.default_rng(seed).choice(len(arr), n - len(arr), replace=True)
    message = f"object '{object_id}': point cloud has {len(arr)} points, the gate reads {n}; repeated {n - len(arr)}"
    warnings.warn(message, ResampledCloudWarning, stacklevel=2)
    log.warning(message)
    return np.concatenate([arr, arr[extra]]).astype(np.float32)


def stack_clouds(clouds: Sequence[np.ndarray], n: int, object_ids: Sequence[str] | None = None) -> torch.Tensor:
    """Clouds of any sizes -> (len(clouds), n, 3) float32 tensor (each through :func:`fit_cloud`)."""
    ids = list(object_ids) if object_ids is not None else [f"#{i}" for i in range(len(clouds))]
    if len(ids) != len(clouds):
        raise ArrayError(f"{len(clouds)} clouds but {len(ids)} object ids")
    if not clouds:
        return torch.zeros(0, n, 3)
    return torch.from_numpy(
        np.stack([fit_cloud(c, n, i, seed=k) for k, (c, i) in enumerate(zip(clouds, ids, strict=True))])
    )


def library_clouds(library, object_ids: Sequence[str], n: int, *, seed: int = 0) -> torch.Tensor:
    """(len(object_ids), n, 3) float32 farthest-point surface clouds of library objects (object frame, m).

    library: a :class:`ges_core.objects.library.ObjectLibrary`; each cloud is ``n`` farthest points of
    ``4 n`` seeded surface samples (:func:`ges_core.objects.pointcloud.sample_surface`).
    """
    clouds = [library.point_cloud(oid, n, seed=seed, fps=True)[0] for oid in object_ids]
    return stack_clouds(clouds, n, object_ids)


def augment(points: torch.Tensor, config: AugmentConfig, generator: torch.Generator) -> torch.Tensor:
    """A randomly rotated (about z) and scaled copy of points: (B, N, 3); unchanged if disabled."""
    if not config.enabled:
        return points
    batch = points.shape[0]
    out = points
    if config.rotate_z:
        angle = torch.rand(batch, generator=generator) * (2 * torch.pi)
        c, s = torch.cos(angle), torch.sin(angle)
        x, y = out[..., 0], out[..., 1]
        out = torch.stack([c[:, None] * x - s[:, None] * y, s[:, None] * x + c[:, None] * y, out[..., 2]], dim=-1)
    if config.scale > 0:
        factor = 1.0 + (torch.rand(batch, generator=generator) * 2.0 - 1.0) * config.scale
        out = out * factor[:, None, None]
    return out
