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

__all__ = ["place_on_table", "stable_rotation", "support_margin", "tilt_rise", "transform_primitive"]


# A pose counts as rolling when tilting it ROLL_TILT_DEG about some horizontal axis lifts the centre of mass less
# than ROLL_FLOOR above the lowest hull point (:func:`tilt_rise`). Measured on the real set: the YCB soup can on its
# side +0.07 mm (PyBullet rolls it 85 cm in 2 s), upright +2.3 mm; boxes lying flat +1.3-4.0 mm; fruit and tools
# +0.04-0.9 mm whatever their pose (docs/objects.md, "Resting placement").
ROLL_TILT_DEG = 5.0
"""Tilt of :func:`tilt_rise`'s test, degrees (above the resting check's 3 degrees, :mod:`ges_core.synthesis`)."""
ROLL_FLOOR = 0.0005
"""Rise below which the most probable pose counts as rolling, m."""
ROLL_GAIN = 3.0
"""A rolling most probable pose gives way only to a pose whose rise is at least this many times its own."""
ROLL_MIN_SHARE = 0.25
"""...and whose probability is at least this share of the most probable pose's."""


def stable_rotation(mesh: trimesh.Trimesh) -> np.ndarray:
    """(4, 4) transform of the resting pose (only its rotation is used): the most probable quasi-static pose of
    trimesh's ``compute_stable_poses`` (deterministic with ``sigma = 0``), unless that pose rolls (:func:`tilt_rise`
    under :data:`ROLL_FLOOR`, a can on its side) while another pose of at least :data:`ROLL_MIN_SHARE` of its
    probability rises :data:`ROLL_GAIN` times as much and over the floor (the can upright): then the most probable
    such pose.

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
    transforms, probs = trimesh.poses.compute_stable_poses(mesh, center_mass=com, n_samples=1, sigma=0.0, threshold=0.0)
    if len(transforms) == 0:
        return np.eye(4)
    out = np.eye(4)
    out[:3, :3] = transforms[_steadiest(transforms, probs, np.asarray(hull.vertices), com)][:3, :3]
    return out


def _steadiest(transforms: np.ndarray, probs: np.ndarray, hull_vertices: np.ndarray, com: np.ndarray) -> int:
    """Index of the pose :func:`stable_rotation` takes among ``transforms`` (P, 4, 4), sorted by ``probs`` (P,)."""

    def rise(i: int) -> float:
        rotation, shift = transforms[i][:3, :3], transforms[i][:3, 3]
        return tilt_rise(hull_vertices @ rotation.T + shift, rotation @ com + shift)

    first = rise(0)
    if first >= ROLL_FLOOR:
        return 0
    for i in range(1, len(transforms)):
        if probs[i] < ROLL_MIN_SHARE * probs[0]:
            break
        if (r := rise(i)) >= ROLL_FLOOR and r >= ROLL_GAIN * first:
            return i
    return 0


def tilt_rise(vertices: np.ndarray, com: np.ndarray, tilt_deg: float = ROLL_TILT_DEG, axes: int = 16) -> float:
    """How far the centre of mass ``com`` (3,) rises above the lowest of ``vertices`` (V, 3) (an object's convex
    hull in a resting pose, z up, m) when the object is tilted ``tilt_deg`` about the worst of ``2 * axes``
    horizontal axes, m. Positive: every such tilt must lift the object, so it rocks back (a box on a face: about
    ``margin * sin(tilt)``); near 0 or negative: it rolls or tips (a cylinder on its side, an egg on its tip)."""
    offsets = np.asarray(vertices, dtype=np.float64) - np.asarray(com, dtype=np.float64)
    height = -offsets[:, 2].min()
    angle, worst = np.radians(tilt_deg), np.inf
    for a in np.linspace(0.0, np.pi, axes, endpoint=False):
        for sign in (1.0, -1.0):
            turned = Rotation.from_rotvec(sign * angle * np.array([np.cos(a), np.sin(a), 0.0])).apply(offsets)
            worst = min(worst, -turned[:, 2].min() - height)
    return float(worst)


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
