"""Points on a hand's collision geometry, per link, from its URDF: a cheap stand-in for the hand's surface.

Used where a link *origin* is too coarse, e.g. keeping a candidate grasp's palm off the table: the
Allegro palm's origin sat 15 mm above the table while its 45 mm-deep collision box pressed it with 480 N.
Each ``<collision>`` gives a few points on its surface, in the link frame: a box its 8 corners, a sphere
its 6 poles, a cylinder or capsule 8 points around each end (a capsule's hemispheres add its two end
points), a mesh the vertices of its convex hull (at most ``max_mesh_points``, evenly subsampled).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ges_core.errors import AssetError
from ges_core.urdf import parse_urdf

__all__ = ["collision_points"]


def collision_points(urdf_text: str, *, max_mesh_points: int = 24) -> dict[str, np.ndarray]:
    """``{link: (P, 3) points}`` on each link's collision geometry, link frame, metres (links without any left out)."""
    out: dict[str, np.ndarray] = {}
    for link in parse_urdf(urdf_text).iter("link"):
        points = [_shape_points(c, max_mesh_points) for c in link.findall("collision")]
        points = [p for p in points if len(p)]
        if points:
            out[link.get("name")] = np.concatenate(points)
    return out


def _shape_points(collision, max_mesh_points: int) -> np.ndarray:
    geometry = collision.find("geometry")
    if geometry is None or len(geometry) == 0:
        return np.zeros((0, 3))
    shape = geometry[0]
    local = _local_points(shape, max_mesh_points)
    origin = collision.find("origin")
    xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
    rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
    return local @ Rotation.from_euler("xyz", rpy).as_matrix().T + xyz  # URDF rpy: extrinsic x, y, z


def _local_points(shape, max_mesh_points: int) -> np.ndarray:
    kind = shape.tag
    if kind == "box":
        half = np.array([float(v) for v in shape.get("size").split()]) / 2
        return np.array(list(itertools.product(*[(-h, h) for h in half])))
    if kind == "sphere":
        r = float(shape.get("radius"))
        return np.concatenate([np.eye(3) * r, -np.eye(3) * r])
    if kind in ("cylinder", "capsule"):
        r, length = float(shape.get("radius")), float(shape.get("length"))
        angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        ring = np.stack([r * np.cos(angles), r * np.sin(angles), np.zeros(8)], axis=1)
        ends = [ring + [0, 0, length / 2], ring - [0, 0, length / 2]]
        if kind == "capsule":
            ends.append(np.array([[0, 0, length / 2 + r], [0, 0, -length / 2 - r]]))
        return np.concatenate(ends)
    if kind == "mesh":
        return _mesh_points(shape, max_mesh_points)
    raise AssetError(
        f"collision_points: unknown URDF geometry <{kind}>; expected box, sphere, cylinder, capsule or mesh"
    )


def _mesh_points(shape, max_mesh_points: int) -> np.ndarray:
    import trimesh

    path = Path(shape.get("filename", "").removeprefix("file://"))
    if not path.is_file():
        raise AssetError(f"collision_points: mesh '{path}' not found; the hand's URDF must carry absolute mesh paths")
    mesh = trimesh.load(path, force="mesh")
    scale = np.array([float(v) for v in shape.get("scale", "1 1 1").split()])
    hull = mesh.convex_hull.vertices * scale
    if len(hull) > max_mesh_points:
        hull = hull[np.linspace(0, len(hull) - 1, max_mesh_points).round().astype(int)]
    return np.asarray(hull, dtype=np.float64)
