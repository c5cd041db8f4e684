"""Shape features of one object, from its processed mesh and its surface point cloud.

>>> obj = library.processed("procedural/mug/000")                 # the cached processed mesh (not reprocessed)
>>> points, _ = library.point_cloud("procedural/mug/000", 2048, seed=0)
>>> shape_features(obj.mesh, points, volume=obj.volume)           # (F,) in FEATURE_NAMES order

Each feature, and why it is there (the experts split objects by how a hand must hold them; the paper's expert
preferences are "small flat objects", "medium objects", "larger box-shaped objects"):

- ``extent_1_m >= extent_2_m >= extent_3_m``: the sides of the minimum-volume oriented bounding box, sorted.
  Size against the hand's span decides power grasp versus pinch; the oriented box, not the axis-aligned one,
  so a yawed object measures the same.
- ``pca_ratio_2_1``, ``pca_ratio_3_1``: the surface points' covariance eigenvalues over the largest one
  (``l2/l1``, ``l3/l1``): scale-free elongation (rods: both small) and flatness (plates: only the last small);
  a sphere or a cube gives 1, 1.
- ``log10_volume_m3``: how much there is to hold (mass at a given density). The logarithm: the library dataset's
  volumes span six decades (a thin random_urdfs shell, 2e-9 m^3, to the YCB cracker box, 2e-3 m^3), and raw
  volume would put every small object at one standardized value while one large object became a cluster of its
  own.
- ``hull_ratio``: volume / convex-hull volume (solidity). 1 for convex shapes, below for mugs, bowls, brackets:
  concavities and handles give a hand other surfaces to pinch or hook.
- ``sphericity``: ``pi^(1/3) (6 V)^(2/3) / A``, the surface-area-to-volume ratio made scale-free (1 for a ball,
  lower for thin plates and sheets): raw ``A / V`` has units 1/m and only repeats the size already given.
- ``height_ratio``: the height in the resting pose (z extent) over the longest side: tall objects are grasped
  from the side, flat-lying ones from above (Stage 1's horizontal / vertical strategy), which the rotation-free
  features above cannot tell apart.
- ``com_height_ratio``: the centre of mass height over the height: a bowl or a cone (low) against a mug or a
  top-heavy object (high) -- the paper names a large centroid shift among its hard cases.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ges_core.errors import AssetError

__all__ = ["FEATURE_NAMES", "FEATURE_UNITS", "check_features", "object_features", "shape_features"]

FEATURE_NAMES: tuple[str, ...] = (
    "extent_1_m",
    "extent_2_m",
    "extent_3_m",
    "pca_ratio_2_1",
    "pca_ratio_3_1",
    "log10_volume_m3",
    "hull_ratio",
    "sphericity",
    "height_ratio",
    "com_height_ratio",
)
"""Names of the features, in vector order."""
FEATURE_UNITS: tuple[str, ...] = ("m", "m", "m", "1", "1", "log10(m^3)", "1", "1", "1", "1")
"""Unit of each feature ("1": dimensionless)."""


def shape_features(mesh: trimesh.Trimesh, points: np.ndarray, *, volume: float | None = None) -> np.ndarray:
    """(F,) float64 shape features of one object, in :data:`FEATURE_NAMES` order (module docstring).

    mesh: the watertight surface mesh in its resting frame (z up, table at the lowest point), metres.
    points: (n, 3) surface samples of it, same frame, metres (n >= 4), e.g. ``ObjectLibrary.point_cloud``.
    volume: m^3 of the solid when known (:attr:`ProcessedObject.volume` counts overlapping bodies once); default
    the mesh's own volume. Values may be NaN for a broken mesh: :func:`check_features` names them.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4:
        raise AssetError(f"shape_features: points must be (n >= 4, 3), got shape {points.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):  # a degenerate mesh gives NaN: check_features names it
        return _features(mesh, points, volume)


def _features(mesh: trimesh.Trimesh, points: np.ndarray, volume: float | None) -> np.ndarray:
    vol = float(mesh.volume) if volume is None else float(volume)
    extents = np.sort(np.asarray(mesh.bounding_box_oriented.primitive.extents, dtype=np.float64))[::-1]
    eig = np.sort(np.linalg.eigvalsh(np.cov(points.T)))[::-1]
    hull_volume = float(mesh.convex_hull.volume)
    height = float(mesh.extents[2])
    # trimesh divides by the signed mesh volume: only a closed, outward mesh has a centre of mass
    com_height = float(mesh.center_mass[2] - mesh.bounds[0, 2]) if mesh.volume > 0 else math.nan
    return np.array(
        [
            *extents,
            _ratio(eig[1], eig[0]),
            _ratio(eig[2], eig[0]),
            math.log10(vol) if vol > 0 else math.nan,
            _ratio(vol, hull_volume),
            _ratio(math.pi ** (1 / 3) * (6 * max(vol, 0.0)) ** (2 / 3), float(mesh.area)),
            _ratio(height, extents[0]),
            _ratio(com_height, height),
        ],
        dtype=np.float64,
    )


def _ratio(a: float, b: float) -> float:
    """a / b, NaN when b is not positive (a degenerate mesh: :func:`check_features` reports it)."""
    return float(a) / float(b) if b > 0 else math.nan


def check_features(object_id: str, features: np.ndarray) -> np.ndarray:
    """``features`` if all are finite, else AssetError naming the object and each bad feature."""
    bad = [f"{name} = {value}" for name, value in zip(FEATURE_NAMES, features, strict=True) if not np.isfinite(value)]
    if bad:
        raise AssetError(
            f"object '{object_id}': shape feature(s) not finite: {', '.join(bad)} (a flat, open or empty mesh?); "
            "check it with 'ges objects list --sizes --objects ID'"
        )
    return features


def object_features(library, object_id: str, *, points: int, seed: int) -> np.ndarray:
    """(F,) checked features of ``object_id`` from ``library`` (an :class:`~ges_core.objects.ObjectLibrary`): its
    processed mesh (the library's disk cache for file meshes; procedural shapes are rebuilt in milliseconds) and
    a ``points``-point surface cloud sampled with ``seed``."""
    obj = library.processed(object_id)
    cloud, _ = library.point_cloud(object_id, points, seed=seed)
    return check_features(object_id, shape_features(obj.mesh, cloud, volume=obj.volume))
