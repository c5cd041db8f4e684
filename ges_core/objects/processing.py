"""From an :class:`ObjectEntry` to a repaired, placed mesh and its collision shapes.

Steps: build (procedural) or load (file, URDF scale) → size checks and face limit (:mod:`.bounds`) → repair
and validate → optional scale
normalization → resting placement (lowest point at z = 0, centre of mass above the origin) →
write the mesh, content-addressed, under ``<cache_dir>/objects/meshes`` → collision shapes.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from ges_core.errors import AssetError
from ges_core.objects.asset import ConvexPart, PrimitiveShape
from ges_core.objects.bounds import DEFAULT_MAX_FACES, bounded_hull, check_extent, limit_faces
from ges_core.objects.decompose import (
    CoacdSettings,
    cached_parts,
    decompose,
    hull_depth,
    hull_tolerance,
    mesh_to_obj_bytes,
    settings_for,
)
from ges_core.objects.placement import GRASPABLE_WIDTH, place_on_table, transform_primitive
from ges_core.objects.procedural import build_shape, shape_seed
from ges_core.objects.processed_cache import cache_key, load_processed, store_processed
from ges_core.objects.sources import ObjectEntry
from ges_core.objects.validate import CONVEX_RATIO, check_finite, load_mesh_file, repair_mesh
from ges_core.paths import atomic_write_bytes, cache_dir

__all__ = [
    "CollisionKind",
    "ProcessedObject",
    "collision_shapes",
    "collision_volume",
    "min_width",
    "process_entry",
    "solid_volume",
]

CollisionKind = Literal["primitive", "convex", "near_convex", "convex_parts", "concave"]
"""``primitive``: exact shapes; ``convex``: the mesh's own hull; ``near_convex``: one body whose surface lies
within :func:`.decompose.hull_tolerance` of its hull, which it collides as (no CoACD); ``convex_parts``: the
mesh is several convex bodies (pybullet's random_urdfs, VHACD files), each its own part; ``concave``: needs
CoACD."""

WIDTH_BLOCK = 4_000_000
"""Most entries of one block of :func:`min_width`'s vertex x face-normal projections (32 MB): a hull of
4,000 vertices and 8,000 faces would otherwise take 256 MB at once."""

VOLUME_SAMPLES = 100_000
"""Monte-Carlo points for the overlap volume of overlapping bodies (teddy's 15 hulls overlap by a
fraction of a percent; the estimate's error scales with the overlap, not the whole volume)."""


@dataclass(frozen=True, kw_only=True)
class ProcessedObject:
    """One object's geometry, ready for collision assembly, sampling and size checks."""

    entry: ObjectEntry
    mesh: trimesh.Trimesh
    """Repaired mesh in the resting object frame (z = 0 at the lowest point), metres."""
    mesh_path: Path
    """The same mesh as an OBJ file in the cache (content-addressed)."""
    mesh_hash: str
    """16 hex digits of the SHA-256 of that file (decomposition cache key)."""
    kind: CollisionKind
    primitives: tuple[PrimitiveShape, ...] = ()
    volume: float
    """m^3 of the solid (overlapping bodies counted once)."""
    hull_depth: float = 0.0
    """m, deepest point of the surface below its convex hull (one-body file meshes; 0 otherwise)."""
    min_width: float | None = None
    """m, :func:`min_width` of the mesh, kept for file meshes (their processing is cached on disk)."""


def process_entry(
    entry: ObjectEntry, *, normalize_size: float | None = None, max_faces: int = DEFAULT_MAX_FACES
) -> ProcessedObject:
    """Build or load ``entry``'s mesh, repair it, optionally scale its largest extent to
    ``normalize_size`` (m), place it at rest, and write it to the mesh cache.

    max_faces: a loaded mesh with more faces is simplified to this many first (:func:`.bounds.limit_faces`).
    Raises AssetError naming the object when it cannot be used: ``entry.problem``, an unreadable, broken or
    flat mesh, or (without ``normalize_size``) one larger than :data:`.bounds.MAX_EXTENT`.
    """
    if entry.problem is not None:
        raise AssetError(f"{entry.object_id}: {entry.problem}")
    key = cache_key(entry, normalize_size=normalize_size, max_faces=max_faces)
    cached = load_processed(key, entry) if key is not None else None
    if cached is not None:
        return cached
    obj = _process(entry, normalize_size=normalize_size, max_faces=max_faces)
    if key is not None:
        store_processed(key, obj)
    return obj


def _process(entry: ObjectEntry, *, normalize_size: float | None, max_faces: int) -> ProcessedObject:
    mesh, kind, primitives = _raw_geometry(entry, max_faces=max_faces, check_size=normalize_size is None)
    # procedural shapes are built upright; a file mesh takes its most probable resting pose unless told otherwise
    placed, transform = place_on_table(
        mesh,
        rotate=entry.source != "procedural" and entry.rest != "as_authored",
        max_width=GRASPABLE_WIDTH if entry.rest == "graspable" else None,
    )
    primitives = tuple(transform_primitive(p, transform) for p in primitives)
    if normalize_size is not None:  # after placement: scaling about the origin keeps the rest pose
        factor = normalize_size / float(np.max(placed.extents))
        placed.apply_scale(factor)
        primitives = tuple(_scale_primitive(p, factor) for p in primitives)
    data = mesh_to_obj_bytes(placed)
    digest = hashlib.sha256(data).hexdigest()[:16]
    path = cache_dir("objects", "meshes") / f"{digest}.obj"
    if not path.is_file():
        atomic_write_bytes(path, data)
    volume = solid_volume(placed)
    depth, width = 0.0, None
    if kind is None:  # a file mesh, classified at its final size (the hull test is in metres)
        width = min_width(placed)
        kind, depth = _classify(placed, width)
    return ProcessedObject(
        entry=entry, mesh=placed, mesh_path=path, mesh_hash=digest, kind=kind, primitives=primitives, volume=volume,
        hull_depth=depth, min_width=width,
    )  # fmt: skip


def _raw_geometry(
    entry: ObjectEntry, *, max_faces: int, check_size: bool
) -> tuple[trimesh.Trimesh, CollisionKind | None, tuple[PrimitiveShape, ...]]:
    """The repaired mesh, its collision kind (None for a file mesh: classified once placed) and primitives."""
    if entry.source == "procedural":
        shape = build_shape(entry.category, shape_seed(entry.seed, entry.category, entry.index))
        return repair_mesh(shape.mesh, name=entry.object_id), shape.kind, shape.primitives
    return _load_file(entry, max_faces=max_faces, check_size=check_size), None, ()


def _load_file(entry: ObjectEntry, *, max_faces: int, check_size: bool) -> trimesh.Trimesh:
    """The repaired mesh of a file entry; the cheap checks (finite, size) run before the face limit and repair."""
    name = f"{entry.object_id} ({entry.path})"
    mesh = load_mesh_file(entry.path, scale=entry.scale)
    check_finite(mesh, name=name)
    if check_size:
        check_extent(mesh, name=name, user=entry.source == "user")
    mesh, name = limit_faces(mesh, max_faces, name=name)
    return repair_mesh(mesh, name=name)


def _classify(mesh: trimesh.Trimesh, width: float) -> tuple[CollisionKind, float]:
    """The collision kind of a file mesh of narrowest width ``width`` (m), and its depth below its hull (m;
    one body only, else 0)."""
    bodies = mesh.split(only_watertight=False)
    convex = [b.volume >= CONVEX_RATIO * b.convex_hull.volume for b in bodies]
    if all(convex):
        return ("convex" if len(bodies) == 1 else "convex_parts"), 0.0
    if len(bodies) > 1:
        return "concave", 0.0
    depth = hull_depth(mesh)
    return ("near_convex" if depth <= hull_tolerance(width) else "concave"), depth


def _scale_primitive(prim: PrimitiveShape, factor: float) -> PrimitiveShape:
    pose = tuple(v * factor for v in prim.pose[:3]) + tuple(prim.pose[3:])
    return PrimitiveShape(kind=prim.kind, size=tuple(s * factor for s in prim.size), pose=pose)


def solid_volume(mesh: trimesh.Trimesh, *, seed: int = 0) -> float:
    """Volume (m^3) of the solid: the bodies' exact volumes, minus a seeded Monte-Carlo estimate of
    their overlaps when some overlap (estimating only the overlap keeps the error small)."""
    bodies = mesh.split(only_watertight=False)
    if len(bodies) == 1:
        return float(mesh.volume)
    inside = [_inside_test(b) for b in bodies]
    if not _bodies_overlap(bodies, inside):
        return float(mesh.volume)
    lo, hi = mesh.bounds
    points = np.random.default_rng(seed).uniform(lo, hi, size=(VOLUME_SAMPLES, 3))
    count = np.zeros(len(points), dtype=np.int64)
    for body, test in zip(bodies, inside, strict=True):
        near = _boxes_intersect(body.bounds, points[:, None, :].repeat(2, axis=1))
        count[near] += test(points[near])
    overlap = np.maximum(count - 1, 0).mean() * np.prod(hi - lo)
    return float(mesh.volume - overlap)


def _inside_test(body: trimesh.Trimesh):
    """``points (n, 3) -> (n,) bool`` strictly inside ``body``: half-space tests for a convex body
    (100x faster than ray casting), else trimesh's ray-parity ``contains``."""
    if body.volume < CONVEX_RATIO * body.convex_hull.volume:
        return body.contains
    hull = body.convex_hull
    normals, offsets = hull.face_normals, np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
    return lambda points: np.all(points @ normals.T < offsets, axis=1)


def _bodies_overlap(bodies: list[trimesh.Trimesh], inside: list) -> bool:
    """Whether a vertex of one body lies strictly inside another (touching bodies do not count).
    Only pairs whose bounding boxes intersect are tested: pybullet objects have up to 127 bodies."""
    bounds = np.array([b.bounds for b in bodies])  # (n, 2, 3)
    for i, body in enumerate(bodies):
        inner = _shrunk_vertices(body)
        for j in np.flatnonzero(_boxes_intersect(bounds[i], bounds)):
            if j != i and inside[j](inner).any():
                return True
    return False


def _boxes_intersect(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(n,) bool: axis-aligned ``box`` (2, 3) intersects each of ``boxes`` (n, 2, 3)."""
    return np.all((boxes[:, 0] < box[1]) & (boxes[:, 1] > box[0]), axis=1)


def _shrunk_vertices(body: trimesh.Trimesh) -> np.ndarray:
    """Vertices moved 1 % toward the body's centroid, so a vertex lying on a neighbour's face is not
    counted inside it."""
    centre = body.vertices.mean(axis=0)
    return centre + 0.99 * (body.vertices - centre)


def collision_shapes(
    obj: ProcessedObject, settings: CoacdSettings, *, compute: bool
) -> tuple[PrimitiveShape | ConvexPart, ...]:
    """The collision set of ``obj``; for a concave mesh, the cached CoACD parts (computed now when
    ``compute``, else an AssetError saying how to prepare them)."""
    if obj.kind == "primitive":
        return obj.primitives
    if obj.kind in ("convex", "near_convex"):
        return (ConvexPart(path=_write_hull(obj.mesh)),)
    if obj.kind == "convex_parts":
        return tuple(ConvexPart(path=_write_hull(b)) for b in obj.mesh.split(only_watertight=False))
    settings = settings_for(obj.mesh, settings)
    parts = cached_parts(obj.mesh_hash, settings)
    if parts is None and not compute:
        oid = obj.entry.object_id
        raise AssetError(
            f"{oid}: concave mesh has no cached convex decomposition (CoACD settings {settings.key()}); "
            f"run `{prepare_command(obj.entry)}` or load it with decompose=True"
        )
    if parts is None:
        parts = decompose(obj.mesh, obj.mesh_hash, settings, name=obj.entry.object_id)
    return tuple(ConvexPart(path=p) for p in parts)


def collision_volume(shapes: tuple[PrimitiveShape | ConvexPart, ...]) -> float:
    """m^3: the sum of the shapes' volumes (overlaps counted twice, as SAPIEN and PyBullet count mass)."""
    return float(sum(_shape_volume(s) for s in shapes))


def _shape_volume(shape: PrimitiveShape | ConvexPart) -> float:
    if isinstance(shape, ConvexPart):
        return _part_volume(Path(shape.path))
    size = shape.size
    if shape.kind == "box":
        return 8.0 * size[0] * size[1] * size[2]
    ball = 4.0 / 3.0 * np.pi * size[0] ** 3
    if shape.kind == "sphere":
        return ball
    tube = np.pi * size[0] ** 2 * 2.0 * size[1]
    return tube + ball if shape.kind == "capsule" else tube


@functools.cache  # part files are content-addressed (same path, same hull): ObjectLibrary.get asks per attempt
def _part_volume(path: Path) -> float:
    """m^3 of the convex hull of the part file at ``path``."""
    return float(trimesh.load(path, force="mesh", process=False).convex_hull.volume)


def prepare_command(entry: ObjectEntry) -> str:
    """The ``ges objects prepare`` command line that decomposes ``entry`` (its source's options included)."""
    where = {"real": " --source real", "pybullet": " --source pybullet", "procedural": " --source procedural"}
    option = where.get(entry.source, "")
    if entry.source == "user" and entry.path is not None:
        option = f" --user-dir {entry.path.parent.parent}"
    return f"ges objects prepare{option} --objects {entry.object_id}"


def _write_hull(mesh: trimesh.Trimesh) -> Path:
    """Convex hull of ``mesh`` (at most :data:`.bounds.HULL_FACES` faces) written content-addressed under
    ``<cache_dir>/objects/hulls``."""
    data = mesh_to_obj_bytes(bounded_hull(mesh))
    path = cache_dir("objects", "hulls") / f"{hashlib.sha256(data).hexdigest()[:16]}.obj"
    if not path.is_file():
        atomic_write_bytes(path, data)
    return path


def min_width(mesh: trimesh.Trimesh) -> float:
    """Smallest width (m) of the convex hull over its face normals: the narrowest opening a
    parallel-jaw or thumb-finger grasp across the object needs (an upper bound on the exact width). The hull
    has at most :data:`.bounds.HULL_FACES` faces; the projections are taken in blocks of :data:`WIDTH_BLOCK`."""
    hull = bounded_hull(mesh)
    vertices, normals = hull.vertices, hull.face_normals
    step = max(1, WIDTH_BLOCK // len(vertices))
    widths = []
    for start in range(0, len(normals), step):
        proj = vertices @ normals[start : start + step].T  # (n_vertices, step)
        widths.append(np.min(proj.max(axis=0) - proj.min(axis=0)))
    return float(min(widths))
