"""A hand's collision geometry as the engines see it, and how far its convex hulls are off the meshes.

Both engines collide a URDF ``<collision>`` mesh as its convex hull (PyBullet 3.2.7 and SAPIEN
3.0.3 alike), one hull per ``<collision>`` element. Two measurements say where that is wrong:

* :func:`hull_gap`: how deep the mesh's surface lies below its hull (a palm's finger sockets);
* :func:`pair_overlaps`: links that may touch (not an excluded pair, see
  :meth:`ges_core.hand.HandModel.excluded_link_pairs`) whose hulls overlap at a pose where the meshes do not.

Shapes are in link frames (metres); poses come from :class:`~ges_core.kinematics.HandKinematics`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError
from ges_core.hand_prep.meshes import resolve_mesh_path
from ges_core.urdf import origin_matrix, parse_urdf

__all__ = [
    "CLOSURES",
    "HULL_OVERLAP_TOL",
    "engine_link_shapes",
    "hand_link_poses",
    "LinkShape",
    "PairOverlap",
    "hull_gap",
    "hull_penetration",
    "link_shapes",
    "mesh_gap",
    "pair_overlaps",
    "sat_overlap",
]

HULL_OVERLAP_TOL = 1e-3
"""m: hulls that overlap more than this beyond the meshes' own overlap count (the linter's self-collision
tolerance: shallower overlaps are within the engines' contact offsets)."""
CLOSURES = (0.3, 0.6, 0.9)
"""Fractions of :meth:`HandDescription.closed_pose` checked besides the open pose: the poses a grasp passes."""
SAMPLES = 800
"""Surface points per mesh for :func:`mesh_gap` (seeded, plus the vertices); the gap is exact for the second
mesh's surface, so the error is how far the closest point of the first lies from a sample (~0.5 mm here)."""
EDGE_AXES = 80
"""Edge directions per hull in the separating-axis test (evenly subsampled): 80 x 80 axes. Dropping axes can
only raise the measured depth; face normals (all kept) decide most pairs. 300 took 0.27 s per pair."""


@dataclass(frozen=True)
class LinkShape:
    """One ``<collision>`` element of a link."""

    link: str
    mesh: object
    """trimesh.Trimesh in the link frame, metres (the mesh itself, or the primitive)."""
    source: Path | None
    """The mesh file, None for a primitive."""
    transform: np.ndarray
    """(4, 4) link frame <- file frame: the ``<origin>`` times the mesh ``scale``."""
    whole: object = None
    """For a convex part of a decomposed mesh: the whole mesh (link frame), the real shape; else None."""

    @property
    def primitive(self) -> bool:
        """A box, sphere, cylinder or capsule: its hull is the shape."""
        return self.source is None and self.whole is None

    @property
    def real(self):
        """The real shape this collision stands for (the whole mesh of a part)."""
        return self.mesh if self.whole is None else self.whole

    @property
    def hull(self):
        """What the engines collide: the convex hull (a primitive is its own)."""
        return self.mesh if self.source is None else self.mesh.convex_hull


@dataclass(frozen=True)
class PairOverlap:
    """Two links whose hulls overlap at a pose."""

    link_a: str
    link_b: str
    pose: str
    """Which pose: ``open`` or ``closed``."""
    hull_overlap: float
    """How deep the hulls reach into each other (deepest surface point inside the other), metres (> 0)."""
    mesh_gap: float
    """Distance between the real meshes, metres (< 0: they overlap by that much)."""


def link_shapes(urdf_text: str, base_dir: Path, *, capsules: bool = True) -> dict[str, list[LinkShape]]:
    """Link -> its collision shapes, placed in the link frame (``<origin>`` and mesh ``scale`` applied).

    capsules: read ``<capsule>`` elements (False: left out, as every shape of an unknown tag)."""
    out: dict[str, list[LinkShape]] = {}
    for link in parse_urdf(urdf_text).findall("link"):
        shapes = [_shape(link.get("name"), c, base_dir, capsules) for c in link.findall("collision")]
        if shapes := [s for s in shapes if s is not None]:
            out[link.get("name")] = shapes
    return out


def _shape(link: str, collision, base_dir: Path, capsules: bool = True) -> LinkShape | None:
    import trimesh

    geometry = collision.find("geometry")
    if geometry is None or not len(geometry):
        return None
    g, source = geometry[0], None
    if g.tag == "mesh":
        source = resolve_mesh_path(g.get("filename", ""), base_dir)
        if not source.is_file():
            raise AssetError(
                f"link '{link}': collision mesh {source} does not exist; fix the URDF's filename or install the "
                "package that holds it"
            )
        mesh = trimesh.load(str(source), force="mesh")
        scale = np.diag([*(float(s) for s in g.get("scale", "1 1 1").split()), 1.0])
    elif g.tag == "box":
        mesh = trimesh.creation.box(extents=[float(s) for s in g.get("size").split()])
    elif g.tag == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=float(g.get("radius")))
    elif g.tag == "cylinder":
        mesh = trimesh.creation.cylinder(radius=float(g.get("radius")), height=float(g.get("length")), sections=32)
    elif g.tag == "capsule" and capsules:
        # length: the cylinder part, axis z (PyBullet, SAPIEN and the Shadow converter read it so); 16 x 16 vertices:
        # the polyhedron lies within 2 % of the radius inside the capsule (0.14 mm on the Shadow's)
        mesh = trimesh.creation.capsule(height=float(g.get("length")), radius=float(g.get("radius")), count=[16, 16])
    else:
        return None
    transform = origin_matrix(collision) @ (scale if source is not None else np.eye(4))
    mesh.apply_transform(transform)
    return LinkShape(link, mesh, source, transform)


def hull_gap(mesh) -> float:
    """Deepest point of ``mesh``'s surface below its convex hull, metres (0 for a convex mesh)."""
    from ges_core.objects.decompose import hull_depth

    return hull_depth(mesh)


def hull_penetration(a: np.ndarray, b: np.ndarray) -> float:
    """Penetration depth of two convex hulls given by their vertices (N, 3), (M, 3), metres; 0 if apart.

    Separating-axis test over every face normal of both hulls and every cross product of their edge
    directions: the smallest overlap of the two projections is the depth (exact for convex polytopes).
    """
    if np.any(a.min(0) > b.max(0)) or np.any(b.min(0) > a.max(0)):
        return 0.0  # bounding boxes apart
    depth = sat_overlap(a, b, np.concatenate([_face_normals(a), _face_normals(b)]))
    if depth <= 0.0:
        return 0.0  # a face plane separates them: no need for the many edge axes
    return max(0.0, min(depth, sat_overlap(a, b, _edge_crosses(a, b))))


def sat_overlap(a: np.ndarray, b: np.ndarray, axes: np.ndarray) -> float:
    """Smallest overlap of the two point sets' projections on ``axes`` (A, 3) unit vectors, metres."""
    if len(axes) == 0:
        return float("inf")
    pa, pb = a @ axes.T, b @ axes.T  # (N, A), (M, A)
    return float(np.minimum(pa.max(0) - pb.min(0), pb.max(0) - pa.min(0)).min())


def _face_normals(points: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull

    return ConvexHull(points).equations[:, :3]


def _edge_crosses(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    da, db = _edge_directions(a), _edge_directions(b)
    cross = np.cross(da[:, None, :], db[None, :, :]).reshape(-1, 3)
    norm = np.linalg.norm(cross, axis=1)
    return cross[norm > 1e-9] / norm[norm > 1e-9, None]


def _edge_directions(points: np.ndarray, limit: int = EDGE_AXES) -> np.ndarray:
    """Unit directions of a hull's edges (duplicates of parallel edges dropped, at most ``limit``)."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    edges = np.concatenate([hull.simplices[:, [0, 1]], hull.simplices[:, [1, 2]], hull.simplices[:, [0, 2]]])
    d = points[edges[:, 1]] - points[edges[:, 0]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d *= np.where(d[:, :1] < 0, -1.0, 1.0)  # one sign per direction
    d = np.unique(np.round(d, 4), axis=0)
    return d[:: max(1, len(d) // limit)]


def mesh_gap(a, b) -> float:
    """Distance between two meshes' surfaces (both already placed), metres; negative when one reaches into the other.

    Seeded surface samples of each are projected onto the other (exact closest points); a sample inside
    the other (watertight meshes only) counts as a negative distance.
    """
    return min(_one_way_gap(a, b), _one_way_gap(b, a))


def _one_way_gap(a, b) -> float:
    import trimesh
    from scipy.spatial import cKDTree

    points, _ = trimesh.sample.sample_surface(a, SAMPLES, seed=0)
    points = np.concatenate([np.asarray(a.vertices), points])
    hull = b.convex_hull
    in_hull = (points @ hull.face_normals.T - np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])).max(1) < 0
    # Exact distances only where the minimum can be: a surface point lies within one edge length of a vertex,
    # so a point whose nearest vertex is farther than (nearest of all + longest edge) cannot be the closest.
    near_vertex, _ = cKDTree(np.asarray(b.vertices)).query(points)
    keep = in_hull | (near_vertex <= near_vertex.min() + float(b.edges_unique_length.max()))
    points, in_hull = points[keep], in_hull[keep]
    _, dist, _ = trimesh.proximity.closest_point(b, points)
    if b.is_watertight and in_hull.any():  # ray tests only for points inside b's hull (cheap plane test first)
        inside = np.zeros(len(points), dtype=bool)
        inside[in_hull] = b.contains(points[in_hull])
        dist = np.where(inside, -dist, dist)
    return float(dist.min())


def pair_overlaps(
    shapes: dict[str, list[LinkShape]],
    poses: dict[str, dict[str, np.ndarray]],
    excluded: set[frozenset[str]],
    tol: float,
) -> list[PairOverlap]:
    """Link pairs that may collide whose hulls overlap by more than ``tol`` beyond the meshes' own overlap.

    poses: pose name -> link -> (4, 4) link pose in the base frame. excluded: pairs that never collide
    (:meth:`ges_core.hand.HandModel.excluded_link_pairs`).
    """
    names = sorted(shapes)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if frozenset((a, b)) in excluded or all(s.primitive for s in shapes[a] + shapes[b]):
                continue  # never collide, or primitives only (each collides as itself)
            depths = {name: _hull_depth(shapes[a], shapes[b], pose[a], pose[b]) for name, pose in poses.items()}
            found = _first_clean_overlap(shapes[a], shapes[b], poses, depths, tol)
            if found is not None:
                out.append(PairOverlap(a, b, *found))
    return out


def _first_clean_overlap(
    sa: list[LinkShape],
    sb: list[LinkShape],
    poses: dict[str, dict[str, np.ndarray]],
    depths: dict[str, float],
    tol: float,
) -> tuple[str, float, float] | None:
    """(pose, hull overlap, mesh gap) at the pose of deepest hull overlap where the real shapes are at most
    ``tol`` into each other and the hulls reach more than ``tol`` further; None if no pose qualifies.

    Poses where the real links already collide (a finger curled into the palm at 90 % closure, 7-12 mm deep
    on the Ability hand) are left out: there the hulls' extra depth is not what stops a grasp, and the parts of
    a decomposition, cut faces and all, are not comparable with the whole meshes."""
    for name in sorted(depths, key=depths.get, reverse=True):
        if depths[name] <= tol:
            return None
        pose = poses[name]
        real = _point_depth(sa, sb, pose[sa[0].link], pose[sb[0].link], real=True)
        if real < -tol:
            continue
        hull = _point_depth(sa, sb, pose[sa[0].link], pose[sb[0].link], real=False)
        if hull - max(0.0, -real) > tol:
            return name, hull, real
    return None


def _hull_depth(sa: list[LinkShape], sb: list[LinkShape], ta: np.ndarray, tb: np.ndarray) -> float:
    """Penetration depth (separating axes) of the deepest pair of hulls of links a and b, metres: the screen."""
    hulls_a = [_placed(s.hull.vertices, ta) for s in sa]
    hulls_b = [_placed(s.hull.vertices, tb) for s in sb]
    return max(hull_penetration(x, y) for x in hulls_a for y in hulls_b)


def _point_depth(sa: list[LinkShape], sb: list[LinkShape], ta: np.ndarray, tb: np.ndarray, *, real: bool) -> float:
    """:func:`mesh_gap` of links a and b: between the hulls the engines collide (``real=False``, as an
    overlap >= 0) or between the real shapes, the whole meshes of parts (``real=True``, as a signed gap).

    Both are measured the same way (deepest surface point inside the other), so their difference is the
    hulls' own error; the separating-axis depth of :func:`hull_penetration` is another measure (how far to
    push the bodies apart) and only screens."""
    if real:
        shapes_a = list({id(x.real): x.real for x in sa}.values())
        shapes_b = list({id(y.real): y.real for y in sb}.values())
        return min(mesh_gap(_placed_mesh(x, ta), _placed_mesh(y, tb)) for x in shapes_a for y in shapes_b)
    pairs = [
        (x.hull, y.hull)
        for x in sa
        for y in sb
        if hull_penetration(_placed(x.hull.vertices, ta), _placed(y.hull.vertices, tb)) > 0.0
    ]  # hulls the separating-axis test finds apart cannot overlap: no need to measure them
    gaps = [mesh_gap(_placed_mesh(x, ta), _placed_mesh(y, tb)) for x, y in pairs]
    return max(0.0, -min(gaps)) if gaps else 0.0


def _placed(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return np.asarray(points) @ pose[:3, :3].T + pose[:3, 3]


def _placed_mesh(mesh, pose: np.ndarray):
    out = mesh.copy()
    out.apply_transform(pose)
    return out


def engine_link_shapes(urdf_text: str, base_dir: Path) -> dict[str, list[LinkShape]]:
    """:func:`link_shapes` as the engines will load them: a mesh ``ges hand prepare`` decomposed is its parts.

    Each part is a convex shape of its own (``source`` = the part file), so its hull is itself.
    """
    from ges_core.hand_prep.decompose import cached_link_parts
    from ges_core.hand_prep.meshes import NATIVE_FORMATS, converted_mesh_if_cached

    out = {}
    for link, shapes in link_shapes(urdf_text, base_dir).items():
        placed = []
        for shape in shapes:
            loaded = shape.source
            if loaded is not None and loaded.suffix not in NATIVE_FORMATS:
                loaded = converted_mesh_if_cached(loaded)
            parts = cached_link_parts(loaded) if loaded is not None else None
            placed += _part_shapes(shape, parts) if parts else [shape]
        out[link] = placed
    return out


def _part_shapes(shape: LinkShape, parts: list[Path]) -> list[LinkShape]:
    """The convex parts of ``shape``'s mesh, placed as the mesh is (its ``<origin>`` and scale)."""
    import trimesh

    out = []
    for part in parts:
        mesh = trimesh.load(str(part), force="mesh")
        mesh.apply_transform(shape.transform)
        out.append(LinkShape(shape.link, mesh, None, shape.transform, shape.mesh))  # a convex part: its own hull
    return out


def hand_link_poses(hand, links: list[str]) -> dict[str, dict[str, np.ndarray]]:
    """Pose name -> link -> (4, 4) base-frame pose at the open pose and the closing poses of :data:`CLOSURES`.

    hand: a :class:`~ges_core.hand.HandModel`; joints with couplings applied."""
    import torch

    from ges_core.kinematics import shared_kinematics

    d = hand.description
    named = {"open": d.apply_couplings(np.asarray(d.open_pose, dtype=float))}
    named.update({f"closed {c:.0%}": d.closed_pose(c) for c in CLOSURES})
    kin = shared_kinematics(hand)
    placed = kin.link_poses(torch.as_tensor(np.stack(list(named.values()))), links).numpy()
    return {name: dict(zip(links, placed[i], strict=True)) for i, name in enumerate(named)}
