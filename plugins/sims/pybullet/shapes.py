"""An :class:`~ges_core.objects.asset.ObjectAsset`'s collision shapes as PyBullet sees them.

* Shapes: primitives map to PyBullet primitives; capsule and cylinder axes are local **x** in
  the asset (as in SAPIEN) but local **z** in PyBullet, so their frames turn by +90 deg about y.
  Convex parts are ``GEOM_MESH`` files (PyBullet builds their convex hull).
* Mass properties are computed here, exactly, from ``density`` x the shapes' volumes
  (analytic for primitives, the convex hull via trimesh for parts), as SAPIEN/PhysX computes
  them. PyBullet itself would take a compound's or a hull's inertia from its bounding box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.transforms import matrix_to_quat, quat_mul, quat_to_matrix

__all__ = ["MassProperties", "convex_hull", "lowest_point", "mass_properties", "shape_arrays"]

Z_TO_X = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
"""wxyz rotation by +90 deg about y: takes PyBullet's capsule/cylinder axis (z) onto the asset's (x)."""
_SIZES = {"box": 3, "sphere": 1, "capsule": 2, "cylinder": 2}
"""Number of ``size`` values per primitive kind."""


@dataclass(frozen=True)
class MassProperties:
    """Mass, centre of mass and principal inertia of an object, object frame."""

    mass: float
    """kg."""
    inertial_pose: np.ndarray
    """(7,) pose of the principal inertial frame (origin at the centre of mass), object frame, wxyz."""
    inertia: np.ndarray
    """(3,) principal moments about ``inertial_pose``'s axes, kg m^2."""


def mass_properties(obj: ObjectAsset) -> MassProperties:
    """``density`` x volume of every collision shape (overlaps counted twice, as in SAPIEN)."""
    parts = [_unit_density_part(shape) for shape in _shapes(obj)]
    volumes = np.array([v for v, _, _ in parts])
    total = float(volumes.sum())
    com = sum(v * c for v, c, _ in parts) / total
    tensor = sum(inertia + v * _parallel_axis(c - com) for v, c, inertia in parts)
    moments, axes = np.linalg.eigh(obj.density * tensor)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    pose = np.concatenate([com, matrix_to_quat(axes)])
    return MassProperties(mass=obj.density * total, inertial_pose=pose, inertia=np.maximum(moments, 0.0))


def shape_arrays(obj: ObjectAsset) -> dict[str, list]:
    """Keyword arguments of ``createCollisionShapeArray`` for the object's shapes (xyzw frames)."""
    from .engine import p

    keys = ("shapeTypes", "radii", "halfExtents", "lengths", "fileNames", "collisionFramePositions")
    out: dict[str, list] = {k: [] for k in (*keys, "collisionFrameOrientations", "meshScales")}
    for shape in _shapes(obj):
        kind, radius, half, length, name, pose = _pybullet_shape(shape, p)
        for key, value in zip(keys, (kind, radius, half, length, name, pose[:3].tolist()), strict=True):
            out[key].append(value)
        out["collisionFrameOrientations"].append([*pose[4:].tolist(), float(pose[3])])
        out["meshScales"].append([1.0, 1.0, 1.0])
    return out


def lowest_point(obj: ObjectAsset) -> float:
    """Lowest z of the collision shapes, object frame at identity orientation, metres."""
    return min(_lowest(shape) for shape in _shapes(obj))


@lru_cache(maxsize=256)
def convex_hull(path: Path):
    """The convex hull (a ``trimesh.Trimesh``) of a convex part's mesh file, as PyBullet builds it."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds; we name the file
        raise AssetError(f"cannot read convex part {path}: {type(exc).__name__}: {exc}") from exc
    try:
        hull = mesh.convex_hull
    except Exception as exc:  # noqa: BLE001 - qhull fails on flat or degenerate point sets
        raise AssetError(f"convex part {path} has no volume (qhull: {type(exc).__name__}); use a closed mesh") from exc
    if hull.volume <= 0:
        raise AssetError(f"convex part {path} has no volume; re-export it as a closed mesh")
    return hull


# -- per shape ------------------------------------------------------------------------------------
def _shapes(obj: ObjectAsset) -> tuple[PrimitiveShape | ConvexPart, ...]:
    if not obj.collision:
        raise AssetError(f"object '{obj.object_id}' has no collision shapes; give it a primitive or convex parts")
    for shape in obj.collision:
        if isinstance(shape, PrimitiveShape):
            _check_primitive(shape, obj.object_id)
    return obj.collision


def _check_primitive(shape: PrimitiveShape, object_id: str) -> None:
    if shape.kind not in _SIZES:
        raise AssetError(f"object '{object_id}': unknown primitive kind '{shape.kind}'; use one of {list(_SIZES)}")
    if len(shape.size) != _SIZES[shape.kind] or min(shape.size) <= 0:
        raise AssetError(
            f"object '{object_id}': a {shape.kind} needs {_SIZES[shape.kind]} positive size values, got {shape.size}"
        )
    if len(shape.pose) != 7:
        raise AssetError(f"object '{object_id}': a shape pose has 7 values (xyz + wxyz), got {len(shape.pose)}")


def _unit_density_part(shape: PrimitiveShape | ConvexPart) -> tuple[float, np.ndarray, np.ndarray]:
    """(volume m^3, centre (3,) object frame, inertia (3, 3) about the centre per unit density)."""
    if isinstance(shape, ConvexPart):
        hull = convex_hull(Path(shape.path))
        return float(hull.volume), np.asarray(hull.center_mass), np.asarray(hull.moment_inertia) / hull.density
    volume, local = _primitive_inertia(shape)
    rot = quat_to_matrix(np.asarray(shape.pose[3:]))
    return volume, np.asarray(shape.pose[:3], dtype=np.float64), rot @ np.diag(local) @ rot.T


def _primitive_inertia(shape: PrimitiveShape) -> tuple[float, np.ndarray]:
    """(volume, principal moments (3,) per unit density in the shape frame); capsule/cylinder axis x."""
    if shape.kind == "box":
        a, b, c = shape.size
        v = 8 * a * b * c
        return v, v / 3 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    if shape.kind == "sphere":
        (r,) = shape.size
        v = 4 / 3 * math.pi * r**3
        return v, np.full(3, 0.4 * v * r * r)
    r, h = shape.size
    v_cyl = math.pi * r * r * 2 * h
    if shape.kind == "cylinder":
        return v_cyl, np.array([v_cyl * r * r / 2, *[v_cyl * (3 * r * r + 4 * h * h) / 12] * 2])
    v_sph = 4 / 3 * math.pi * r**3  # the two end caps
    axial = v_cyl * r * r / 2 + v_sph * 0.4 * r * r
    perp = v_cyl * (r * r / 4 + h * h / 3) + v_sph * (0.4 * r * r + h * h + 0.75 * h * r)
    return v_cyl + v_sph, np.array([axial, perp, perp])


def _parallel_axis(d: np.ndarray) -> np.ndarray:
    return float(d @ d) * np.eye(3) - np.outer(d, d)


def _pybullet_shape(shape: PrimitiveShape | ConvexPart, p) -> tuple:
    """(type, radius, half extents, length, file name, (7,) frame wxyz) for one shape."""
    if isinstance(shape, ConvexPart):
        return p.GEOM_MESH, 0.0, [0.0] * 3, 0.0, str(_obj_file(Path(shape.path))), np.array([0, 0, 0, 1.0, 0, 0, 0])
    pose = np.asarray(shape.pose, dtype=np.float64)
    if shape.kind == "box":
        return p.GEOM_BOX, 0.0, list(shape.size), 0.0, "", pose
    if shape.kind == "sphere":
        return p.GEOM_SPHERE, shape.size[0], [0.0] * 3, 0.0, "", pose
    kind = p.GEOM_CAPSULE if shape.kind == "capsule" else p.GEOM_CYLINDER
    turned = np.concatenate([pose[:3], quat_mul(pose[3:], Z_TO_X)])
    return kind, shape.size[0], [0.0] * 3, 2 * shape.size[1], "", turned


def _obj_file(path: Path) -> Path:
    """PyBullet reads Wavefront OBJ: other formats are converted once into the cache."""
    if path.suffix.lower() == ".obj":
        return path
    from ges_core.paths import atomic_write_text, cache_dir, file_sha256

    out = cache_dir("pybullet", "convex") / f"{path.stem}_{file_sha256(path)}.obj"
    if not out.is_file():
        atomic_write_text(out, convex_hull(path).export(file_type="obj"))
    return out


def _lowest(shape: PrimitiveShape | ConvexPart) -> float:
    if isinstance(shape, ConvexPart):
        return float(convex_hull(Path(shape.path)).vertices[:, 2].min())
    rot = quat_to_matrix(np.asarray(shape.pose[3:]))
    z = shape.pose[2]
    if shape.kind == "box":
        return float(z - np.abs(rot[2]) @ np.asarray(shape.size))
    if shape.kind == "sphere":
        return float(z - shape.size[0])
    r, h = shape.size
    axis_z = abs(rot[2, 0])  # z component of the local x axis
    rim = r if shape.kind == "capsule" else r * math.sqrt(max(0.0, 1 - axis_z * axis_z))
    return float(z - h * axis_z - rim)
