"""Convex decomposition of a hand's link meshes with CoACD, cached by mesh hash.

The objects' decomposition (:mod:`ges_core.objects.decompose`) does the work and owns the cache
layout (``<cache>/objects/coacd/<mesh hash>-<settings key>/part_NNN.obj`` + ``manifest.json``);
hands use their own settings, :data:`HAND_COACD`, so a hand mesh and an object mesh with the same
bytes never share parts made for the other. The key is the hash of the mesh file the engine loads
(after any OBJ conversion), so a decomposition is found again from the URDF alone.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from ges_core.hand_prep.engine_files import note_parts_written
from ges_core.objects.decompose import FAST, cached_parts, decompose, decomposition_dir
from ges_core.paths import file_sha256

__all__ = ["HAND_COACD", "cached_link_parts", "decompose_link_mesh", "decomposition_seconds"]

# CoACD's FAST settings of the objects (6.5x faster than its defaults) with CoACD's default concavity threshold
# 0.05 instead of FAST's 0.08. Measured on the Ability hand (2026-12-01, shared 2-core machine): the distal
# phalanx idx-F2_C.obj (hull 7.3 mm off the mesh) gave 4 parts at 0.08 (3.9 s), 7 at 0.05 (5.2 s) and 12 at
# 0.03 (16.8 s); the palm gave 5 parts at each.
HAND_COACD = replace(FAST, threshold=0.05)
"""CoACD arguments for hand link meshes."""


def cached_link_parts(mesh: Path) -> list[Path] | None:
    """Convex part files of a decomposed link mesh (the file an engine loads), or None if never decomposed."""
    if not mesh.is_file():
        return None
    return cached_parts(file_sha256(mesh), HAND_COACD)


def decompose_link_mesh(mesh: Path, *, name: str) -> list[Path]:
    """Decompose ``mesh`` (cached: a second call only reads the manifest); returns the part files."""
    import trimesh

    key = file_sha256(mesh)  # hashed once: the cache lookup and the decomposition share it
    parts = cached_parts(key, HAND_COACD)
    if parts is not None:
        return parts
    parts = decompose(trimesh.load(str(mesh), force="mesh"), key, HAND_COACD, name=name)
    note_parts_written()  # engine URDFs made before in this process lack these parts
    return parts


def decomposition_seconds(mesh: Path) -> float:
    """CoACD's run time for ``mesh`` as its manifest recorded it, seconds (0 when not decomposed)."""
    manifest = decomposition_dir(file_sha256(mesh), HAND_COACD) / "manifest.json"
    return float(json.loads(manifest.read_text())["seconds"]) if manifest.is_file() else 0.0
