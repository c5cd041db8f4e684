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

__all__ = [
    "HAND_COACD",
    "HAND_MAX_PARTS",
    "cached_link_parts",
    "decompose_link_mesh",
    "decomposition_seconds",
    "parts_gap",
]

HAND_MAX_PARTS = 16
"""Convex parts per hand link mesh at most (CoACD's ``max_convex_hull``: past it, CoACD merges the parts whose merge
adds the least concavity). Every part is a shape both engines collide at every step. The Inspire hand's .glb meshes
gave 12-140 parts each without a cap, 583 shapes for the hand (the Allegro 23, the Shadow 22, the Ability 60); with
16 it has 211, and Stage 1 took 13 % (procedural) and 24 % (real scans) less CPU per object with the same
single-trial verdicts, its parts reaching at most 3.1 mm beyond a finger's mesh as before, 10.7 instead of 7.6 mm
beyond the palm's (``benchmarks/hand_parts.py``, docs/hands/assets.md). Meshes under the cap decompose exactly as
without it (the Ability hand's 5 and 7 parts: the same files, the same hand hash)."""

# CoACD's FAST settings of the objects (6.5x faster than its defaults) with CoACD's default concavity threshold
# 0.05 instead of FAST's 0.08. Measured on the Ability hand (2026-12-01, shared 2-core machine): the distal
# phalanx idx-F2_C.obj (hull 7.3 mm off the mesh) gave 4 parts at 0.08 (3.9 s), 7 at 0.05 (5.2 s) and 12 at
# 0.03 (16.8 s); the palm gave 5 parts at each.
HAND_COACD = replace(FAST, threshold=0.05, max_convex_hull=HAND_MAX_PARTS)
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


def parts_gap(mesh, parts: list[Path]) -> float:
    """How far a decomposition's convex parts reach beyond ``mesh``: the deepest point of the mesh's surface inside any
    part, metres (0 when every part hugs the surface). The measure of :func:`ges_core.hand_prep.geometry.hull_gap`
    taken per part (the same surface samples): a fingertip meets the parts that much before the mesh."""
    import trimesh

    from ges_core.objects.decompose import hull_depth

    return max([0.0] + [hull_depth(mesh, trimesh.load(str(p), force="mesh")) for p in parts])
