"""Grasp quality: the Ferrari-Canny epsilon of a set of point contacts with friction.

Model (the standard one of GraspIt! and Dex-Net):

- *Point contact with friction*, no torsional (soft-finger) friction: a finger pushes along the
  inward normal ``-n`` and may add a tangential force up to ``mu`` times the normal force.
- The Coulomb cone is linearized into ``cone_edges`` edges ``f_ij = -n_i + mu (cos a_j t1 + sin a_j t2)``,
  each with a *unit normal component* (so the edge length is ``sqrt(1 + mu^2)``).
- Each edge gives a primitive wrench ``w_ij = [f_ij, lambda (p_i - c) x f_ij]`` about a centre ``c``;
  ``lambda`` (the torque scale, 1/m) makes torques commensurate with forces.
- The grasp wrench space is the convex hull of all primitive wrenches (the "L1" or sum-of-normal-forces
  variant: total normal force at most 1). ``epsilon`` is the radius of the largest origin-centred ball
  inside that hull, i.e. the smallest distance from the origin to a hull facet; 0 when the origin is
  not strictly inside (no force closure) or the hull is flat (fewer than 6 independent wrenches).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scipy.spatial import ConvexHull, QhullError

from ges_core.arrays import checked_array
from ges_core.config import ConfigModel
from ges_core.errors import ArrayError

__all__ = [
    "ForceClosureConfig",
    "cone_forces",
    "ferrari_canny",
    "primitive_wrenches",
    "tangent_frames",
    "wrench_space_epsilon",
]

RANK_TOL = 1e-9
"""Relative singular-value threshold below which the wrenches span fewer than 6 dimensions; qhull
would either raise on such a flat input or return facets within round-off of the origin."""

EPS_FLOOR = 1e-12
"""epsilon below this is round-off of an origin on the hull boundary (e.g. antipodal contacts)."""


class ForceClosureConfig(ConfigModel):
    """Friction and scaling of the Ferrari-Canny epsilon."""

    mu: float = Field(0.5, ge=0.0, description="Coulomb friction coefficient; 0.5 is Dex-Net's default friction_coef")
    cone_edges: int = Field(
        8, ge=3, le=64, description="edges of the linearized friction cone; 8 as in Dex-Net's num_cone_faces"
    )
    torque_scale: float | None = Field(
        None,
        gt=0.0,
        description="lambda, 1/m, multiplying torques; None = 1/radius (the object's radius about the centre), "
        "which makes epsilon unitless and independent of the object's size",
    )


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (n, 3) each, orthogonal to the unit ``normals`` (n, 3) and to each other.

    Deterministic: the helper axis is the world axis least aligned with each normal.
    """
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


def cone_forces(normals: np.ndarray, mu: float, edges: int) -> np.ndarray:
    """Linearized friction-cone edges (n, edges, 3): inward unit normal force plus ``mu`` tangential."""
    nrm = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    t1, t2 = tangent_frames(nrm)
    ang = 2.0 * np.pi * np.arange(edges) / edges
    tang = np.cos(ang)[None, :, None] * t1[:, None] + np.sin(ang)[None, :, None] * t2[:, None]
    return -nrm[:, None, :] + mu * tang


def primitive_wrenches(
    positions: np.ndarray,
    normals: np.ndarray,
    config: ForceClosureConfig | None = None,
    *,
    center: np.ndarray | None = None,
    radius: float | None = None,
) -> np.ndarray:
    """Primitive wrenches (n * cone_edges, 6): force rows then scaled torque about ``center``.

    positions, normals: (n, 3) contact points and *outward* surface normals, object frame, metres.
    center: (3,) torque reference (default: the contacts' mean); radius: metres, used for the
    default torque scale 1/radius (default: largest contact distance from ``center``).
    """
    cfg = config or ForceClosureConfig()
    pos = np.asarray(positions, dtype=np.float64)
    c = pos.mean(axis=0) if center is None else np.asarray(center, dtype=np.float64)
    forces = cone_forces(np.asarray(normals, dtype=np.float64), cfg.mu, cfg.cone_edges)
    lam = cfg.torque_scale if cfg.torque_scale is not None else 1.0 / _radius(pos, c, radius)
    torques = lam * np.cross((pos - c)[:, None, :], forces)
    return np.concatenate([forces, torques], axis=2).reshape(-1, 6)


def _radius(pos: np.ndarray, center: np.ndarray, radius: float | None) -> float:
    """The torque arm normaliser: ``radius`` if given, else the farthest contact (1 m if all coincide)."""
    r = float(np.linalg.norm(pos - center, axis=1).max()) if radius is None else float(radius)
    return r if r > 1e-12 else 1.0


def ferrari_canny(
    positions: np.ndarray,
    normals: np.ndarray,
    config: ForceClosureConfig | None = None,
    *,
    center: np.ndarray | None = None,
    radius: float | None = None,
) -> float:
    """Ferrari-Canny epsilon (L1 variant) of point contacts with friction; 0 without force closure.

    positions, normals: (n, 3), object frame, metres, outward unit normals. See the module
    docstring for the model and :func:`primitive_wrenches` for ``center`` and ``radius``.
    Translating contacts and centre together leaves epsilon unchanged; so does scaling them together
    when ``torque_scale`` is None. Raises ArrayError for malformed input.
    """
    pos, nrm = _checked(positions, normals)
    wrenches = primitive_wrenches(pos, nrm, config, center=center, radius=radius)
    return wrench_space_epsilon(wrenches)


def _checked(positions, normals) -> tuple[np.ndarray, np.ndarray]:
    """float64 (n, 3) positions and normals, n >= 1; ArrayError for wrong shapes, NaN/inf or a zero normal."""
    pos = checked_array(positions, (None, 3), "ferrari_canny: contact positions", layout="object frame, metres")
    nrm = checked_array(normals, (len(pos), 3), "ferrari_canny: contact normals", layout="outward, one per position")
    if len(pos) == 0 or np.any(np.linalg.norm(nrm, axis=1) < 1e-12):
        raise ArrayError("ferrari_canny: give at least one contact, each with a non-zero outward normal")
    return pos, nrm


def wrench_space_epsilon(wrenches: np.ndarray) -> float:
    """Radius of the largest origin-centred ball inside the convex hull of ``wrenches`` (m, 6)."""
    if len(wrenches) < 7 or not np.isfinite(wrenches).all():
        return 0.0
    sv = np.linalg.svd(wrenches, compute_uv=False)
    if sv[-1] <= RANK_TOL * sv[0]:
        return 0.0
    try:
        hull = ConvexHull(wrenches)
    except QhullError:  # flat or otherwise degenerate input: no 6-D interior, no force closure
        return 0.0
    # equations: unit outward facet normals a and offsets b with a.x + b <= 0 inside; origin distance -b
    eps = float(-hull.equations[:, -1].max())
    return eps if eps > EPS_FLOOR else 0.0
