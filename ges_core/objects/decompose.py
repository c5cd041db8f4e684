"""Convex decomposition with CoACD, cached on disk by mesh hash and settings.

Cache layout: ``<cache_dir>/objects/coacd/<mesh_hash>-<settings_key>/part_NNN.obj`` plus
``manifest.json``, written last; a folder without a manifest is an interrupted run and is redone.
Every file is written atomically (temporary file + rename), so a killed run leaves no half file.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import trimesh

from ges_core.errors import AssetError
from ges_core.paths import atomic_write_bytes, atomic_write_text, cache_dir

__all__ = [
    "DEFAULT",
    "FAST",
    "HULL_DEPTH",
    "HULL_DEPTH_SHARE",
    "CoacdSettings",
    "cached_parts",
    "decompose",
    "decomposition_dir",
    "hull_depth",
    "hull_tolerance",
    "mesh_to_obj_bytes",
    "settings_for",
]

HULL_DEPTH = 0.010
"""m: a one-body mesh whose surface lies nowhere deeper than this below its convex hull (and than
:data:`HULL_DEPTH_SHARE` of its narrowest width) collides as its hull, with no CoACD run. The hull then
moves no contact by more than this; a fingertip pad is 15-20 mm wide, so narrower recesses barely change
where it touches. Measured on the real set (benchmarks/coacd_settings.py --real): cans (4.4-6.7 mm, the
rims), boxes (2-8 mm), strawberry, pear (2-4 mm), apple (9 mm, the stem) and the mustard bottle (9 mm) pass;
the foam brick (13 mm), banana (16 mm), marker (6 mm on a 19 mm body), screwdriver and hammer (12-16 mm),
mug (30 mm) and pybullet's bunny, duck and torus (15-23 mm) still get CoACD."""
HULL_SAMPLES = 5_000
"""Surface points of :func:`hull_depth` besides the vertices: for meshes with large faces (an extruded L). On
the real set and pybullet's bunny, duck and torus the vertices alone came within 0.3 mm of 100,000 samples."""
HULL_DEPTH_SHARE = 0.25
"""Of the narrowest width: on thin objects the depth limit shrinks (a 19 mm marker: 4.8 mm, so its 6 mm cap
step keeps CoACD)."""


@dataclass(frozen=True, kw_only=True)
class CoacdSettings:
    """Arguments of ``coacd.run_coacd`` (same names, same meaning)."""

    threshold: float = 0.05
    """Concavity at which a part stops being split (lower: more, tighter parts)."""
    max_convex_hull: int = -1
    """Cap on the number of parts after merging; -1 = no cap."""
    preprocess_mode: str = "auto"
    """Manifold remeshing before decomposition: ``auto`` (only if not manifold), ``on``, ``off``."""
    preprocess_resolution: int = 50
    """Voxel resolution of that remeshing."""
    resolution: int = 2000
    """Surface samples per part for the concavity metric."""
    mcts_nodes: int = 20
    mcts_iterations: int = 150
    mcts_max_depth: int = 3
    merge: bool = True
    decimate: bool = False
    max_ch_vertex: int = 256
    seed: int = 0

    def key(self) -> str:
        """12 hex digits identifying these settings in cache folder names."""
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:12]


DEFAULT = CoacdSettings()
"""CoACD 1.0.14's own defaults."""

FAST = replace(
    DEFAULT,
    threshold=0.08,
    preprocess_resolution=30,
    resolution=1000,
    mcts_nodes=10,
    mcts_iterations=60,
    mcts_max_depth=2,
)
"""Tuned for speed (benchmarks/coacd_settings.py, 5 concave meshes): 6.5x faster than DEFAULT
(mean 34.0 s → 5.2 s per mesh on the shared 2-core machine), volume precision 0.89 → 0.83. A
looser threshold (0.1-0.15) or a part cap (``max_convex_hull``) saved little time but filled
thin-walled bowls and mugs (precision 0.55-0.65); ``preprocess_mode="on"`` was slower and thickened
4 mm walls. Numbers in docs/objects.md."""


SIZE_REF = 0.15
"""m. CoACD's threshold is a concavity relative to the object's size, so on a long object the same threshold
lets a part bridge centimetres: FAST gave the 34 cm hammer 3 parts with 34 % false volume (head and handle in
one hull). :func:`settings_for` lowers it in proportion beyond this length (hammer: 0.036, 9 parts, 8 %;
banana 0.061, screwdriver 0.056). Of the built-in concave objects only procedural bottles taller than 15 cm
(up to 19 cm at 10 per category) change."""


def settings_for(mesh: trimesh.Trimesh, settings: CoacdSettings) -> CoacdSettings:
    """The CoACD settings used for ``mesh`` (metres): ``settings``, with the threshold scaled by
    :data:`SIZE_REF` / longest extent when the mesh is longer than :data:`SIZE_REF` (rounded: a stable cache key)."""
    longest = float(np.max(mesh.extents))
    if longest <= SIZE_REF:
        return settings
    return replace(settings, threshold=round(settings.threshold * SIZE_REF / longest, 4))


def hull_tolerance(width: float) -> float:
    """m of hull depth accepted for an object whose narrowest width is ``width`` (m)."""
    return min(HULL_DEPTH, HULL_DEPTH_SHARE * width)


def hull_depth(mesh: trimesh.Trimesh, hull: trimesh.Trimesh | None = None, *, samples: int = HULL_SAMPLES) -> float:
    """Deepest point of ``mesh``'s surface below its convex hull (m; 0 for a convex mesh).

    The depth of a point inside a convex hull is its distance to the nearest face plane. It is taken at the
    mesh's vertices and at ``samples`` seeded, area-weighted surface points (a large flat face can dip below
    the hull in its middle only: an L-bracket's inner wall is deepest half-way up); the maximum is a lower
    bound that the samples make tight (:data:`HULL_SAMPLES`). hull: the hull to use (default ``mesh.convex_hull``).
    """
    hull = mesh.convex_hull if hull is None else hull
    normals = np.asarray(hull.face_normals)
    offsets = np.einsum("ij,ij->i", normals, hull.triangles[:, 0])
    points, _ = trimesh.sample.sample_surface(mesh, samples, seed=0)
    points = np.concatenate([np.asarray(mesh.vertices), points])
    step = max(1, 4_000_000 // max(len(normals), 1))  # blocks of at most 4M distances (32 MB)
    deepest = 0.0
    for start in range(0, len(points), step):
        dist = offsets[None, :] - points[start : start + step] @ normals.T  # (block, faces), >= 0 inside
        deepest = max(deepest, float(dist.min(axis=1).max()))
    return deepest


def mesh_to_obj_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Geometry-only OBJ text of ``mesh`` (deterministic: same mesh → same bytes)."""
    text = trimesh.exchange.obj.export_obj(
        mesh, include_normals=False, include_color=False, include_texture=False, digits=8, header=None
    )
    return text.encode("utf-8")


def decomposition_dir(mesh_hash: str, settings: CoacdSettings) -> Path:
    """Cache folder of one mesh's decomposition under one setting."""
    return cache_dir("objects", "coacd") / f"{mesh_hash}-{settings.key()}"


def cached_parts(mesh_hash: str, settings: CoacdSettings) -> list[Path] | None:
    """The part files of a finished decomposition, or None if there is none (or it is incomplete)."""
    folder = decomposition_dir(mesh_hash, settings)
    manifest = folder / "manifest.json"
    if not manifest.is_file():
        return None
    parts = [folder / name for name in json.loads(manifest.read_text())["parts"]]
    return parts if all(p.is_file() for p in parts) else None


def decompose(mesh: trimesh.Trimesh, mesh_hash: str, settings: CoacdSettings, *, name: str) -> list[Path]:
    """Run CoACD on ``mesh`` (object frame, metres) and cache the convex parts; returns their files.

    Raises AssetError naming ``name`` when CoACD fails or returns nothing usable.
    """
    import coacd

    coacd.set_log_level("error")
    start = time.perf_counter()
    try:
        raw = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), **asdict(settings))
    except Exception as exc:  # CoACD raises RuntimeError and others from C++
        raise AssetError(f"{name}: CoACD decomposition failed ({type(exc).__name__}: {exc})") from exc
    hulls = [_hull(v, f) for v, f in raw]
    hulls = [h for h in hulls if h is not None]
    if not hulls:
        raise AssetError(
            f"{name}: CoACD returned no usable convex part; check the mesh with `ges objects list --sizes`"
        )
    return _write_parts(hulls, mesh_hash, settings, seconds=time.perf_counter() - start)


def _hull(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh | None:
    """Convex hull of one CoACD part (its faces may be slightly non-convex), or None if flat."""
    try:
        hull = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=True).convex_hull
    except Exception:  # qhull fails on flat or tiny parts
        return None
    return hull if hull.volume > 0 else None


def _write_parts(
    hulls: list[trimesh.Trimesh], mesh_hash: str, settings: CoacdSettings, *, seconds: float
) -> list[Path]:
    folder = decomposition_dir(mesh_hash, settings)
    paths = []
    for i, hull in enumerate(hulls):
        paths.append(atomic_write_bytes(folder / f"part_{i:03d}.obj", mesh_to_obj_bytes(hull)))
    manifest = {"parts": [p.name for p in paths], "seconds": round(seconds, 3), "settings": asdict(settings)}
    atomic_write_text(folder / "manifest.json", json.dumps(manifest, indent=1))
    return paths
