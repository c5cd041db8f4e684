"""Resting placement: the object frame in which an object lies stably on a table at z = 0.

The library bakes this placement into every object's frame: the lowest point is at z = 0 and the
centre of mass is above the origin, so a simulator that puts the object at ``(x, y, table_z)``
with the identity rotation sets it down at rest.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from ges_core.objects.asset import PrimitiveShape
from ges_core.objects.bounds import HULL_FACES, reduce_hull

__all__ = ["place_on_table", "stable_rotation", "support_margin", "transform_primitive"]


def stable_rotation(mesh: trimesh.Trimesh) -> np.ndarray:
    """(4, 4) transform of the most probable quasi-static resting pose (trimesh's
    ``compute_stable_poses``, deterministic with ``sigma = 0``); only its rotation is used.

    The pose depends on the convex hull and the centre of mass only. A hull of more than
    :data:`.bounds.HULL_FACES` faces is simplified to that many first (the cost grows with the square of the
    hull's faces). A centre of mass not strictly inside the hull (a degenerate mesh) keeps the orientation:
    trimesh would look for a centre of mass inside it forever.
    """
    com = mesh.center_mass
    hull = mesh.convex_hull
    if len(hull.faces) > HULL_FACES:
        mesh = hull = reduce_hull(hull)  # trimesh takes the hull of what it is given: the same hull
    if not np.all(np.einsum("ij,ij->i", com - hull.triangles_center, hull.face_normals) < 0):
        return np.eye(4)
    transforms, _probs = trimesh.poses.compute_stable_poses(
        mesh, center_mass=com, n_samples=1, sigma=0.0, threshold=0.0
    )
    if len(transforms) == 0:
        return np.eye(4)
    out = np.eye(4)
    out[:3, :3] = transforms[0][:3, :3]
    return out


def place_on_table(mesh: trimesh.Trimesh, *, rotate: bool) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A copy of ``mesh`` moved into its resting frame, and the (4, 4) transform applied.

    rotate: find the most probable stable pose first (loaded meshes); False keeps the orientation
    (procedural shapes are built upright) and only translates.
    """
    transform = stable_rotation(mesh) if rotate else np.eye(4)
    placed = mesh.copy()
    placed.apply_transform(transform)
    com = placed.center_mass
    shift = np.eye(4)
    shift[:3, 3] = (-com[0], -com[1], -placed.bounds[0, 2])
    placed.apply_transform(shift)
    return placed, shift @ transform


def transform_primitive(prim: PrimitiveShape, transform: np.ndarray) -> PrimitiveShape:
    """``prim`` with its pose premultiplied by the rigid (4, 4) ``transform``."""
    pos = np.asarray(prim.pose[:3])
    w, x, y, z = prim.pose[3:]
    rot = Rotation.from_matrix(transform[:3, :3]) * Rotation.from_quat([x, y, z, w])
    qx, qy, qz, qw = rot.as_quat()
    new_pos = transform[:3, :3] @ pos + transform[:3, 3]
    pose = tuple(float(v) for v in (*new_pos, qw, qx, qy, qz))
    return PrimitiveShape(kind=prim.kind, size=prim.size, pose=pose)


def support_margin(mesh: trimesh.Trimesh, *, tol: float = 1e-5) -> float:
    """Signed distance (m) from the centre of mass's xy to the edge of the support polygon (the convex
    hull of the vertices within ``tol`` of the lowest z): positive inside (stable), negative outside.
    Zero for a point or line support directly under the centre of mass (sphere, lying capsule)."""
    from scipy.spatial import ConvexHull, QhullError

    verts = np.asarray(mesh.vertices)
    support = verts[verts[:, 2] <= verts[:, 2].min() + tol][:, :2]
    com = np.asarray(mesh.center_mass[:2])
    try:
        hull = ConvexHull(support)
    except (QhullError, ValueError):  # point or segment support
        return -float(_distance_to_segment_hull(support, com))
    return float(-np.max(hull.equations[:, :2] @ com + hull.equations[:, 2]))


def _distance_to_segment_hull(points: np.ndarray, p: np.ndarray) -> float:
    """Distance from ``p`` to the segment spanned by collinear ``points`` (n, 2)."""
    if len(points) == 1 or np.ptp(points, axis=0).max() == 0.0:
        return float(np.linalg.norm(points[0] - p))
    direction = points[np.argmax(np.linalg.norm(points - points[0], axis=1))] - points[0]
    t = np.clip((points - points[0]) @ direction / (direction @ direction), 0.0, 1.0)
    lo, hi = points[0] + t.min() * direction, points[0] + t.max() * direction
    seg = hi - lo
    s = 0.0 if not seg.any() else np.clip((p - lo) @ seg / (seg @ seg), 0.0, 1.0)
    return float(np.linalg.norm(lo + s * seg - p))
