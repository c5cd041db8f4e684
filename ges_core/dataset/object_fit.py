"""Does a stored record still fit its object? Its contacts must lie on the surface the library builds now.

A record stores its grasp and contacts, not its object: Stage 2 and a resumed ``ges synth`` rebuild the object
from the library. When the library builds an object differently since the record was made (another mesh, scale
or resting frame), the stored grasp belongs to another object. The contacts are the evidence: Stage 1 samples
them on the object's surface, so they lie on it to round-off (procedural shapes) or within 0.12 mm (15k-face
scans), while a changed object moves them by millimetres to centimetres.

Used by Stage 2 (:func:`ges_core.env.grasp_source.record_asset`, ``ges dataset validate --objects``) and by the
Stage 1 pipeline's resume (:func:`ges_core.synthesis.run.pipeline.run_synthesis` sets such records aside and
makes them again). Reads meshes with trimesh, imported on first use.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ges_core.dataset.record import GraspRecord

__all__ = ["CONTACT_TOLERANCE", "contacts_off_surface", "misfit"]

CONTACT_TOLERANCE = 0.002
"""m: how far a record's contacts may lie from its object's surface. Stage 1 samples them on the surface: on the
procedural library they lie on it to round-off, on the 15k-face real scans within 0.12 mm (the cloud is sampled
from the processed mesh); a changed placement moves them by centimetres."""


def contacts_off_surface(mesh_path: str | Path, points: np.ndarray) -> float:
    """Largest distance, m, from the (n, 3) object-frame ``points`` to the surface mesh at ``mesh_path``."""
    import trimesh

    mesh = trimesh.load(mesh_path, force="mesh", process=False)
    _, distance, _ = trimesh.proximity.closest_point(mesh, np.asarray(points, dtype=np.float64))
    return float(np.max(distance))


def misfit(record: GraspRecord, mesh_path: str | Path, tolerance: float = CONTACT_TOLERANCE) -> str:
    """Why ``record`` does not fit the object whose surface mesh is at ``mesh_path`` ('' when it does, or when it
    holds no contacts to check)."""
    if record.contacts is None:
        return ""
    distance = contacts_off_surface(mesh_path, record.contacts.positions)
    if distance <= tolerance:
        return ""
    return (
        f"its contacts lie up to {distance * 1e3:.1f} mm off the surface of '{record.object_id}' as the library "
        f"builds it now (allowed: {tolerance * 1e3:.1f} mm): the object's mesh or resting frame changed since "
        "Stage 1 ran"
    )
