"""Seeded surface point clouds with outward normals, optionally thinned by farthest-point sampling."""

from __future__ import annotations

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
    labels = _body_labels(mesh)
    bodies = None if labels.max() == 0 else [mesh.submesh([labels == k], append=True) for k in range(labels.max() + 1)]
    got_p, got_n, total, round_ = [], [], 0, 0
    while total < count:
        pts, face = trimesh.sample.sample_surface(mesh, max(count, 64), seed=seed + 7919 * round_)
        nrm = mesh.face_normals[face]
        if bodies is not None:
            keep = _visible(pts, nrm, labels[face], bodies, eps=HIDDEN_EPS * mesh.scale)
            pts, nrm = pts[keep], nrm[keep]
        got_p.append(pts)
        got_n.append(nrm)
        total += len(pts)
        round_ += 1
        if round_ > 50:
            raise AssetError("point sampling found almost no outer surface; is the mesh inside-out?")
    return np.vstack(got_p)[:count], np.vstack(got_n)[:count]


def _body_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """(n_faces,) index of the connected body each face belongs to."""
    return trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))


def _visible(points, normals, owner, bodies, *, eps: float) -> np.ndarray:
    """(n,) bool: the point nudged ``eps``, ``eps / 10`` and ``eps / 100`` along its normal is outside every other
    body (the short probe catches points just under another body's surface)."""
    keep = np.ones(len(points), dtype=bool)
    for k, body in enumerate(bodies):
        for probe in (points + eps * normals, points + 0.1 * eps * normals, points + 0.01 * eps * normals):
            test = (owner != k) & keep
            keep[test] = ~body.contains(probe[test])
    return keep


def farthest_point_indices(points: np.ndarray, n: int) -> np.ndarray:
    """Indices (n,) of a greedy farthest-point subset of ``points`` (m, 3), starting at index 0."""
    m = len(points)
    if n >= m:
        return np.arange(m)
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = 0
    dist = np.linalg.norm(points - points[0], axis=1)
    for i in range(1, n):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen
