"""What a simulator needs to load one object: surface mesh, collision shapes, density."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = ["ConvexPart", "ObjectAsset", "PrimitiveShape"]


@dataclass(frozen=True, kw_only=True)
class PrimitiveShape:
    """An exact primitive collision shape, in the object frame.

    kind: ``box`` (size = half extents x, y, z), ``sphere`` (size = (radius,)),
    ``capsule`` (size = (radius, half_length), axis along local x as in SAPIEN),
    ``cylinder`` (size = (radius, half_length), axis along local x).
    pose: (7,) position (m) + quaternion wxyz of the shape in the object frame.
    """

    kind: Literal["box", "sphere", "capsule", "cylinder"]
    size: tuple[float, ...]
    pose: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class ConvexPart:
    """A convex collision mesh file (from CoACD or a convex source mesh), object frame, metres."""

    path: Path


@dataclass(frozen=True, kw_only=True)
class ObjectAsset:
    """One object, ready to load in any simulator backend."""

    object_id: str
    """Stable id, e.g. ``procedural/mug/003``; unchanged across runs and machines."""
    category: str
    """Category name (for splits and geometry clustering)."""
    mesh_path: Path
    """Watertight surface mesh in the object frame, metres (also the visual).

    Library objects are in their resting frame: lowest point at z = 0, centre of mass over the
    origin, so an identity pose rests them on the table. Backends compute the centre of mass and
    inertia from ``collision`` and ``density`` themselves."""
    collision: tuple[PrimitiveShape | ConvexPart, ...]
    """Collision shapes; all in the object frame."""
    density: float = 500.0
    """kg/m^3; mass = density x collision volume in every backend."""
    mass: float = 0.0
    """kg, density x mesh volume, for reporting and for engines that take a mass."""
    friction: float = 1.0
    """Coulomb friction coefficient of the object's surface."""
