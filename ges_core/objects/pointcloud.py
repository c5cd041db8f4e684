"""Seeded surface point clouds with outward normals, optionally thinned by farthest-point sampling."""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from ges_core.errors import AssetError

__all__ = ["farthest_point_indices", "sample_surface"]

FPS_OVERSAMPLE = 4
"""Candidates per kept point for farthest-point sampling: 4x gives near-uniform spacing; more costs
O(n * candidates) time for little gain."""

HIDDEN_EPS = 1e-3
"""Probe distance, as a fraction of the mesh's size, for dropping points hidden against another body: a
mug handle's flat end cap and the polygonal cup wall part in a gap under 0.1 mm wide beside the face
they share; points there are unreachable by a finger and fail an outward-normal check at 0.1 mm."""


def sample_surface(mesh: trimesh.Trimesh, n: int, *, seed: int = 0, fps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points on the outer surface of ``mesh`` and their outward unit normals.

    Returns points (n, 3) float64 and normals (n, 3) float64, in the mesh frame, metres. Area-weighted
    uniform sampling (seeded); with ``fps`` the points are the farthest-point subset of
    ``4 n`` uniform candidates (even coverage). On a mesh of several bodies, points on faces hidden
    inside or against another body (a handle's end pressed to a cup wall) are dropped.
    """
    if n <= 0:
        raise AssetError(f"point cloud size must be positive, got {n}")
    want = n * (FPS_OVERSAMPLE if fps else 1)
    points, normals = _outer_samples(mesh, want, seed)
    if fps:
        keep = farthest_point_indices(points, n)
        points, normals = points[keep], normals[keep]
    return points, normals


def _outer_samples(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` area-weighted samples from the outer surface (drawing more rounds if some are hidden)."""
    bodies = _bodies(mesh)
    got_p, got_n, total, round_ = [], [], 0, 0
    while total < count:
        pts, face = trimesh.sample.sample_surface(mesh, max(count, 64), seed=seed + 7919 * round_)
        nrm = mesh.face_normals[face]
        if bodies is not None:
            keep = bodies.visible(pts, nrm, face, eps=HIDDEN_EPS * mesh.scale)
            pts, nrm = pts[keep], nrm[keep]
        got_p.append(pts)
        got_n.append(nrm)
        total += len(pts)
        round_ += 1
        if round_ > 50:
            raise AssetError("point sampling found almost no outer surface; is the mesh inside-out?")
    return np.vstack(got_p)[:count], np.vstack(got_n)[:count]


@dataclass(frozen=True)
class _Bodies:
    """The connected bodies of a mesh of several, with what the hidden-surface test asks of each, built once
    per mesh (:func:`_bodies`): a 15-body scan (pybullet's teddy) took 0.4 s per cloud when they were rebuilt
    and ray-tested on every call, against a few ms now."""

    labels: np.ndarray
    """(n_faces,) index of the body each face belongs to."""
    bounds: np.ndarray
    """(n_bodies, 2, 3) each body's axis-aligned bounds."""
    inside: tuple[Callable[[np.ndarray], np.ndarray], ...]
    """Per body, ``points (n, 3) -> (n,) bool`` strictly inside it."""

    def visible(self, points: np.ndarray, normals: np.ndarray, faces: np.ndarray, *, eps: float) -> np.ndarray:
        """(n,) bool: the point nudged ``eps``, ``eps / 10`` and ``eps / 100`` along its normal is outside every
        other body (the short probe catches points just under another body's surface). faces: (n,) the face
        each point lies on."""
        owner = self.labels[faces]
        keep = np.ones(len(points), dtype=bool)
        for k, inside in enumerate(self.inside):
            lo, hi = self.bounds[k]
            for probe in (points + eps * normals, points + 0.1 * eps * normals, points + 0.01 * eps * normals):
                # a point outside the body's box is not strictly inside it: only the others are tested
                test = (owner != k) & keep & np.all((probe > lo) & (probe < hi), axis=1)
                keep[test] = ~inside(probe[test])
        return keep


_CACHE: dict[int, tuple[weakref.ref, _Bodies | None]] = {}
"""id(mesh) -> (weak reference to the mesh, its bodies or None for one body); entries of freed meshes are
dropped on the next look-up."""


def _bodies(mesh: trimesh.Trimesh) -> _Bodies | None:
    """The bodies of ``mesh`` (None when it is one body), computed once per mesh object. The mesh must not
    be changed in place afterwards (the library's processed meshes are not)."""
    hit = _CACHE.get(id(mesh))
    if hit is not None and hit[0]() is mesh:
        return hit[1]
    for key in [k for k, (ref, _) in _CACHE.items() if ref() is None]:
        del _CACHE[key]
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    bodies = None
    if labels.max() > 0:
        parts = [mesh.submesh([labels == k], append=True) for k in range(labels.max() + 1)]
        bodies = _Bodies(labels, np.array([b.bounds for b in parts]), tuple(_inside_test(b) for b in parts))
    _CACHE[id(mesh)] = (weakref.ref(mesh), bodies)
    return bodies


def _inside_test(body: trimesh.Trimesh) -> Callable[[np.ndarray], np.ndarray]:
    """``points (n, 3) -> (n,) bool`` strictly inside ``body``: the face planes of its hull when it is convex (the
    same solid; about 100x faster than casting rays), else trimesh's ray-parity ``contains``. The hull, not the
    body's own faces: a zero-area face has a zero normal, whose plane test no point passes (pybullet's teddy
    has such faces)."""
    if not body.is_convex:
        return body.contains
    hull = body.convex_hull
    normals, offsets = hull.face_normals, np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
    return lambda points: np.all(points @ normals.T < offsets, axis=1)


def farthest_point_indices(points: np.ndarray, n: int, start: np.ndarray | None = None) -> np.ndarray:
    """Indices (n,) of a greedy farthest-point subset of ``points`` (m, 3): ``start`` (indices, default ``[0]``)
    first, then each time the point farthest from every one chosen."""
    m = len(points)
    if n >= m:
        return np.arange(m)
    seeds = np.zeros(1, dtype=np.int64) if start is None else np.asarray(start, dtype=np.int64)
    chosen = np.empty(n, dtype=np.int64)
    chosen[: len(seeds)] = seeds
    dist = np.min(np.linalg.norm(points[:, None] - points[seeds][None], axis=-1), axis=1)
    for i in range(len(seeds), n):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen
