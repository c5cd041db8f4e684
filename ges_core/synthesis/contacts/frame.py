"""PCA of an object's point cloud: grasp strategy, rotational-symmetry test and canonical frame.

All inputs are in the object's resting frame (z up, table at z = 0), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

__all__ = ["Pca", "canonical_frame", "choose_strategy", "horizontal_eig_ratio", "pca", "symmetry_score"]

SYMMETRY_ANGLES_DEG = (37.0, 101.0)
"""Test rotations about the vertical axis: no multiple of 360/k for small k (a square prism maps onto
itself under 90 deg, a hexagonal one under 60 deg), so only a continuous symmetry matches both."""
SIDE_NORMAL_Z = 0.9
"""Points with |n_z| below this (normal > 25 deg from vertical) are side points for the symmetry test."""
SYMMETRY_NEIGHBOURS = 4
"""Nearest original points searched for one with a matching normal."""
NORMAL_MATCH = 0.8
"""Cosine above which two normals belong to the same face (37 deg)."""

WIDTH_TIE = 0.01
"""Hull widths within 1 % of the narrowest count as equally narrow (polygonal round bodies)."""


@dataclass(frozen=True)
class Pca:
    """Principal axes of a point cloud: ``axes[:, i]`` has variance ``variances[i]`` (descending)."""

    mean: np.ndarray
    """(3,) centroid, metres."""
    variances: np.ndarray
    """(3,) m^2, descending."""
    axes: np.ndarray
    """(3, 3) unit eigenvectors as columns."""


def pca(points: np.ndarray) -> Pca:
    """PCA of ``points`` (n, 3)."""
    mean = points.mean(axis=0)
    var, vec = np.linalg.eigh(np.cov((points - mean).T))
    order = np.argsort(var)[::-1]
    return Pca(mean=mean, variances=np.maximum(var[order], 0.0), axes=vec[:, order])


def choose_strategy(p: Pca, *, max_tilt_deg: float, dominance: float) -> str:
    """``horizontal`` when the principal axis is within ``max_tilt_deg`` of z and dominant (its variance
    at least ``dominance`` times the next one: a cube or a ball has no principal axis), else ``vertical``."""
    upright = abs(p.axes[2, 0]) >= np.cos(np.deg2rad(max_tilt_deg))
    dominant = p.variances[0] >= dominance * p.variances[1]
    return "horizontal" if upright and dominant else "vertical"


def symmetry_score(points: np.ndarray, normals: np.ndarray) -> float:
    """How far the cloud is from rotationally symmetric about the vertical axis through its footprint
    centre (bounding-box centre in x, y: the centroid of 1024 samples is ~1 mm off, which alone
    scores like a slightly oval object).

    The side points (normal more than ~25 deg from vertical; horizontal faces map into themselves
    under any rotation about z and carry no information) are rotated about that axis by each of
    :data:`SYMMETRY_ANGLES_DEG`. Each rotated point's distance to the tangent plane of the nearest
    original point with a matching normal (among its SYMMETRY_NEIGHBOURS nearest; matching keeps a
    can's rim from being measured against the lid) is taken, and the score is the 75th percentile,
    divided by the footprint radius. Plane (not point) distances make the score insensitive to
    sampling density: a surface of revolution scores ~0.001-0.02 from 256 to 2048 points, a square
    cube 0.13, an oval (axes 4.95 vs 4.65 cm) 0.02-0.09.
    """
    axis_xy = 0.5 * (points[:, :2].max(axis=0) + points[:, :2].min(axis=0))
    rel = points - np.array([axis_xy[0], axis_xy[1], 0.0])
    radius = float(np.linalg.norm(rel[:, :2], axis=1).max())
    side = np.abs(normals[:, 2]) < SIDE_NORMAL_Z
    if radius <= 0.0 or side.sum() < SYMMETRY_NEIGHBOURS:
        return np.inf
    tree, dists = cKDTree(rel), []
    for ang in np.deg2rad(SYMMETRY_ANGLES_DEG):
        c, s = np.cos(ang), np.sin(ang)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        p, n = rel[side] @ rot.T, normals[side] @ rot.T
        d, idx = tree.query(p, k=SYMMETRY_NEIGHBOURS)
        plane = np.abs(np.einsum("ikj,ikj->ik", p[:, None, :] - rel[idx], normals[idx]))
        match = np.einsum("ikj,ij->ik", normals[idx], n) > NORMAL_MATCH
        best = np.where(match, plane, np.inf).min(axis=1)
        dists.append(np.where(np.isfinite(best), best, d[:, 0]))
    return float(np.percentile(np.concatenate(dists), 75)) / radius


def canonical_frame(points: np.ndarray, symmetric: bool, *, eig_ratio: float) -> np.ndarray:
    """Rotation (3, 3) whose columns are the canonical axes x_c, y_c, z_c in the resting frame.

    ``z_c`` is always the table normal z: the object rests on the table, so a tilted frame would tilt
    the slices and the vertical approach toward the table (the 3-D PCA axis nearest z is 18-44 deg off
    for cubes, balls, capsules, brackets and wedges, whose eigenvalues tie or nearly tie). Symmetric
    objects get z-only alignment with a fixed azimuth (``x_c = x``): every azimuth is equivalent and
    PCA's horizontal axes would be sampling noise. Other objects get the PCA alignment of the
    horizontal plane: ``x_c`` across the smaller horizontal principal axis (its larger component
    positive) and ``y_c = z_c x x_c`` along that axis (the narrow direction). Where the
    horizontal eigenvalues are too close for PCA to fix an azimuth (ratio >= ``eig_ratio``: a square
    cube, a round-ish mug), ``y_c`` is the narrowest horizontal direction of the convex hull instead.
    """
    if symmetric:
        return np.eye(3)
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    var, vec = np.linalg.eigh(np.cov(xy.T))
    y2 = _narrowest_direction(xy, vec[:, 0]) if var[0] >= eig_ratio * var[1] else vec[:, 0]
    x2 = np.array([y2[1], -y2[0]])
    x2 = x2 * (1.0 if x2[np.argmax(np.abs(x2))] > 0 else -1.0)
    return np.array([[x2[0], -x2[1], 0.0], [x2[1], x2[0], 0.0], [0.0, 0.0, 1.0]])


def _narrowest_direction(xy: np.ndarray, minor: np.ndarray) -> np.ndarray:
    """Unit (2,) direction across which the 2-D points are narrowest (rotating calipers on the hull
    edges); among directions within WIDTH_TIE of the narrowest, the one nearest the PCA ``minor`` axis
    (a round body with a handle is equally narrow over a range of directions)."""
    try:
        hull = xy[ConvexHull(xy).vertices]
    except QhullError:  # collinear footprint: across the line
        return minor
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.column_stack([-edges[:, 1], edges[:, 0]]) / np.linalg.norm(edges, axis=1, keepdims=True)
    widths = np.ptp(hull @ normals.T, axis=0)
    close = widths <= widths.min() * (1.0 + WIDTH_TIE)
    return normals[int(np.argmax(np.where(close, np.abs(normals @ minor), -1.0)))]


def horizontal_eig_ratio(points: np.ndarray) -> float:
    """Smaller over larger eigenvalue of the horizontal (x, y) covariance; 1 for a round cross-section."""
    var = np.linalg.eigvalsh(np.cov(points[:, :2].T))
    return float(var[0] / var[1]) if var[1] > 0 else 0.0
