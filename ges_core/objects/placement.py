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

__all__ = [
    "GRASPABLE_WIDTH",
    "narrowest_squeeze",
    "place_on_table",
    "squeeze_samples",
    "stable_rotation",
    "support_margin",
    "tilt_rise",
    "tip_angle",
    "transform_primitive",
]


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
GRASPABLE_WIDTH = 0.12
"""m: with ``rest: graspable``, a pose whose :func:`narrowest_squeeze` is wider gives way (:func:`stable_rotation`).
The contact search's widest squeeze by default (``ContactConfig.max_width``; tests/test_objects_rest_graspable.py
keeps the two equal): a hand grasps across a horizontal slice of the object as it rests."""
SUPPORT_TOL = 0.002
"""m: :func:`tip_angle`'s support is the hull's vertices this close to the table: a scanned box's face is bumpy by a
millimetre or two, and its hull touches the table at 3-5 vertices (the YCB cracker box on a side: 4-8 degrees to
tip at 0.01 mm, 19 at 2 mm, 19.5 at 3 mm)."""
SQUEEZE_MIN_HEIGHT = 0.01
"""m: :func:`narrowest_squeeze` reads no line lower than this (``ContactConfig.min_height``'s default: fingers cannot
reach under the table)."""
SQUEEZE_BAND = 0.02
"""m: :func:`narrowest_squeeze`'s bands: about a fingertip row's spacing (``ContactConfig.finger_spacing``)."""
SQUEEZE_MIN_POINTS = 3
"""A band with fewer points has no meaningful extent (as the contact search's slices)."""
SQUEEZE_MIN_WIDTH = 0.005
"""m: a band narrower than this grazes a face (``ContactConfig.min_width``'s default)."""
SQUEEZE_POINTS = 4096
"""Surface samples (seed 0) :func:`stable_rotation` measures a pose's squeeze on."""
GRASPABLE_TILT_DEG = 10.0
"""A pose taken for its width must not tip over before this tilt, degrees (:func:`tip_angle`): a box on a side tips
at 15-25 degrees, a 1 cm plate on an edge at 3."""


def stable_rotation(mesh: trimesh.Trimesh, *, max_width: float | None = None) -> np.ndarray:
    """(4, 4) transform of the resting pose (only its rotation is used): the most probable quasi-static pose of
    trimesh's ``compute_stable_poses`` (deterministic with ``sigma = 0``), unless that pose rolls (:func:`tilt_rise`
    under :data:`ROLL_FLOOR`, a can on its side) while another pose of at least :data:`ROLL_MIN_SHARE` of its
    probability rises :data:`ROLL_GAIN` times as much and over the floor (the can upright): then the most probable
    such pose.

    ``max_width`` (m; the ``graspable`` rest mode gives :data:`GRASPABLE_WIDTH`): when no squeeze across that pose
    is this narrow (:func:`narrowest_squeeze`: a cereal box lying flat), the most probable pose that has one and
    does not tip over (:data:`GRASPABLE_TILT_DEG`) instead (the box on its side); none such: the pose above. None: no
    width rule.

    Without ``max_width`` the pose depends on the convex hull and the centre of mass only. A hull of more than
    :data:`.bounds.HULL_FACES` faces is simplified to that many first (the cost grows with the square of the
    hull's faces). A centre of mass not strictly inside the hull (a degenerate mesh) keeps the orientation:
    trimesh would look for a centre of mass inside it forever.
    """
    com, surface = mesh.center_mass, mesh
    hull = mesh.convex_hull
    if len(hull.faces) > HULL_FACES:
        mesh = hull = reduce_hull(hull)  # trimesh takes the hull of what it is given: the same hull
    if not np.all(np.einsum("ij,ij->i", com - hull.triangles_center, hull.face_normals) < 0):
        return np.eye(4)
    transforms, probs = trimesh.poses.compute_stable_poses(mesh, center_mass=com, n_samples=1, sigma=0.0, threshold=0.0)
    if len(transforms) == 0:
        return np.eye(4)
    vertices = np.asarray(hull.vertices)
    chosen = _steadiest(transforms, probs, vertices, com)
    if max_width is not None:
        chosen = _narrow_enough(transforms, vertices, com, squeeze_samples(surface), chosen, max_width)
    out = np.eye(4)
    out[:3, :3] = transforms[chosen][:3, :3]
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


def _narrow_enough(
    transforms: np.ndarray,
    hull_vertices: np.ndarray,
    com: np.ndarray,
    samples: np.ndarray,
    chosen: int,
    max_width: float,
) -> int:
    """``chosen`` if that pose has a squeeze at most ``max_width`` wide (:func:`narrowest_squeeze` of the surface
    ``samples`` (N, 3)), else the first (most probable) pose of ``transforms`` (P, 4, 4) that has one and tips over
    only past :data:`GRASPABLE_TILT_DEG`, else ``chosen``."""

    def width(i: int) -> float:
        return narrowest_squeeze(samples @ transforms[i][:3, :3].T)

    if width(chosen) <= max_width:
        return chosen

    def stands(i: int) -> bool:
        rotation = transforms[i][:3, :3]
        return tip_angle(hull_vertices @ rotation.T, rotation @ com) >= GRASPABLE_TILT_DEG

    return next((i for i in range(len(transforms)) if i != chosen and width(i) <= max_width and stands(i)), chosen)


def tip_angle(vertices: np.ndarray, com: np.ndarray, *, tol: float = SUPPORT_TOL) -> float:
    """Degrees an object resting on the lowest of ``vertices`` (V, 3; its convex hull, z up, m) tilts about the
    nearest edge of its support polygon before its centre of mass ``com`` (3,) passes over that edge and it tips
    over: ``atan(support margin / height of the centre of mass)``, the support being the vertices within ``tol`` of
    the lowest. 0 on a point or line support, negative when the centre of mass is outside the support (it is not at
    rest)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    floor = vertices[:, 2].min()
    margin = _support_margin(vertices[vertices[:, 2] <= floor + tol][:, :2], np.asarray(com, dtype=np.float64)[:2])
    return float(np.degrees(np.arctan2(margin, float(com[2]) - floor)))


def squeeze_samples(mesh: trimesh.Trimesh) -> np.ndarray:
    """(:data:`SQUEEZE_POINTS`, 3) seeded surface samples of ``mesh`` in its own frame, m: what
    :func:`stable_rotation` turns into each candidate pose for :func:`narrowest_squeeze`."""
    return trimesh.sample.sample_surface(mesh, SQUEEZE_POINTS, seed=0)[0]


def narrowest_squeeze(
    points: np.ndarray, *, min_height: float = SQUEEZE_MIN_HEIGHT, band: float = SQUEEZE_BAND
) -> float:
    """Narrowest squeeze across an object as it rests, m, read as the contact search reads it: along each of the two
    horizontal principal axes ``d`` of ``points``, the extent along ``d`` of the points in a band ``band`` wide across
    ``d`` (a row of fingertips), least over the bands (of at least :data:`SQUEEZE_MIN_POINTS` points and a squeeze of
    at least :data:`SQUEEZE_MIN_WIDTH`: a band grazing one face is no squeeze; of three bands or more, not the two
    at the ends: they graze the object's ends and rounded corners); points lower than ``min_height`` above the
    lowest are left out. inf when no band qualifies. points: (N, 3) surface samples in the resting pose,
    z up, m. Unlike the convex hull's width it reads a hammer's handle (3 cm), not its head (13 cm)."""
    points = np.asarray(points, dtype=np.float64)
    xy = points[points[:, 2] - points[:, 2].min() >= min_height][:, :2]
    if len(xy) < SQUEEZE_MIN_POINTS:
        return np.inf
    best = np.inf
    for axis in np.linalg.eigh(np.cov(xy, rowvar=False))[1].T:  # the two horizontal principal axes
        along = xy @ axis
        rows = np.floor(xy @ np.array([-axis[1], axis[0]]) / band).astype(np.int64)
        rows -= rows.min()
        count = np.bincount(rows)
        low, high = np.full(len(count), np.inf), np.full(len(count), -np.inf)
        np.minimum.at(low, rows, along)
        np.maximum.at(high, rows, along)
        kept = (count >= SQUEEZE_MIN_POINTS) & (high - low >= SQUEEZE_MIN_WIDTH)
        if len(count) >= 3:  # the end bands graze a side or a rounded corner: less than the object's squeeze
            kept[[0, -1]] = False
        width = (high - low)[kept]
        if len(width):
            best = min(best, float(width.min()))
    return best


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


def place_on_table(
    mesh: trimesh.Trimesh, *, rotate: bool, max_width: float | None = None
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A copy of ``mesh`` moved into its resting frame, and the (4, 4) transform applied.

    rotate: find the most probable stable pose first (loaded meshes; ``max_width`` as :func:`stable_rotation`'s);
    False keeps the orientation (procedural shapes are built upright) and only translates.
    """
    transform = stable_rotation(mesh, max_width=max_width) if rotate else np.eye(4)
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
    verts = np.asarray(mesh.vertices)
    return _support_margin(verts[verts[:, 2] <= verts[:, 2].min() + tol][:, :2], np.asarray(mesh.center_mass[:2]))


def _support_margin(support: np.ndarray, com: np.ndarray) -> float:
    """Signed distance (m) from ``com`` (2,) to the edge of the convex hull of ``support`` (n, 2), positive inside."""
    from scipy.spatial import ConvexHull, QhullError

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
