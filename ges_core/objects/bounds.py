"""Bounds on the work one object costs, so that a huge or mis-scaled mesh fails or shrinks instead of hanging.

Three bounds, each applied where the cost arises:

- :func:`limit_faces`: a loaded mesh with more than ``max_faces`` faces (``LibraryConfig.max_faces``) is
  simplified to that many before repair; repair, convexity, sampling and CoACD all scale with the faces.
- :func:`bounded_hull`: the convex hull that the resting pose, the minimum width and a convex object's
  collision shape are computed from has at most :data:`HULL_FACES` faces.
- :func:`check_extent`: a mesh larger than :data:`MAX_EXTENT` is refused, with a hint at its units.

Measured on a 1,310,720-face sphere (``trimesh.creation.icosphere(subdivisions=8)``, 6 cm): without
these, ``ges objects list --sizes`` ran past 4 minutes at 5 GB (repair 19 s, convexity 15 s, hull 11 s, then
``trimesh.poses.compute_stable_poses`` on a 1.3M-face hull, whose cost grows with the square of the stable
faces; the minimum width would have needed a 655k x 1.3M matrix). With them it takes 16 s and 1 GB.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ges_core.errors import AssetError

__all__ = [
    "DEFAULT_MAX_FACES",
    "HULL_FACES",
    "MAX_EXTENT",
    "bounded_hull",
    "check_extent",
    "limit_faces",
    "reduce_hull",
]

DEFAULT_MAX_FACES = 200_000
"""Default of ``LibraryConfig.max_faces``. Far above what grasp synthesis resolves (a 2048-point cloud, 5
contacts) and above every library object (the largest, pybullet's soccerball, has 9,048). The 1.3M-face
sphere simplified to this is processed in 16 s and 1 GB (load 3 s, simplify 1.5 s, repair 1.7 s, resting
pose 7.6 s); a CoACD decomposition (fast settings) of a 200k-face torus takes 66 s and 0.8 GB, of a
10k-face one 5 s."""

HULL_FACES = 8192
"""Most faces of the hull used for the resting pose, the minimum width and a convex collision shape. A
larger hull is simplified to this many faces (quadric decimation, then the hull of the result). The
resting pose's cost grows with the square of the hull's stable faces: 2.2 s for pybullet's soccerball
(7,260 hull faces, the largest in the library, so every library object keeps its exact pose), 5.5 s for
a sphere's 8,004 (every face stable, the worst case), 50 s for a sphere's 20,480."""

MAX_EXTENT = 1.0
"""m. Largest extent of an object: no hand grasps a 1 m object, and a 60 mm part saved in millimetres
reads as 60 m, one saved in centimetres as 6 m. ``normalize_size`` lifts the check (it rescales anyway)."""


def limit_faces(mesh: trimesh.Trimesh, max_faces: int, *, name: str) -> tuple[trimesh.Trimesh, str]:
    """``mesh`` simplified to ``max_faces`` faces if it has more, and ``name`` extended to say so (for the
    messages of the later steps: a simplified mesh that repair cannot close names the simplification).

    Quadric decimation (``fast-simplification``, through trimesh): keeps sharp features and, as a rule, a
    closed surface closed (repair checks it); 1.5 s for 1.3M faces; deterministic (same input, same mesh).
    """
    faces = len(mesh.faces)
    if faces <= max_faces:
        return mesh, name
    try:
        simple = mesh.simplify_quadric_decimation(face_count=max_faces)
    except ImportError as exc:  # fast-simplification is a core dependency; a broken install lands here
        raise AssetError(
            f"{name}: {faces:,} faces, above the limit of {max_faces:,} (max_faces), and the simplifier is "
            f"missing ({exc}); `pip install fast-simplification` or simplify the mesh in a mesh editor"
        ) from exc
    return simple, f"{name}, simplified from {faces:,} to {len(simple.faces):,} faces (max_faces {max_faces:,})"


def bounded_hull(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The convex hull of ``mesh``, simplified to at most :data:`HULL_FACES` faces when it has more."""
    hull = mesh.convex_hull
    return hull if len(hull.faces) <= HULL_FACES else reduce_hull(hull)


def reduce_hull(hull: trimesh.Trimesh) -> trimesh.Trimesh:
    """A convex hull of about :data:`HULL_FACES` faces, at most, close to ``hull`` (a convex mesh with more).

    The hull of the vertices of ``hull`` decimated to that many faces: a closed mesh of F faces has F / 2 + 2
    vertices, and n points have a hull of at most 2n - 4 faces, so the result has no more faces than the
    decimation kept (it reaches its target on hulls; a sphere's 191,798 faces become 7,986).
    """
    simple = hull.simplify_quadric_decimation(face_count=HULL_FACES)
    return trimesh.Trimesh(simple.vertices, simple.faces, process=False).convex_hull


def check_extent(mesh: trimesh.Trimesh, *, name: str, user: bool) -> None:
    """AssetError if ``mesh`` (metres) is larger than :data:`MAX_EXTENT`, with a hint at its units.

    user: the mesh comes from a user folder, whose scale ``user_scale`` sets (the hint names it).
    """
    size = float(np.max(mesh.extents))
    if size <= MAX_EXTENT:
        return
    raise AssetError(
        f"{name}: the mesh is {size:.4g} m across, larger than any graspable object ({MAX_EXTENT:g} m); "
        f"{_unit_hint(size, user)}"
    )


def _unit_hint(size: float, user: bool) -> str:
    """The fix to suggest for an object of ``size`` m: millimetre units if that makes it graspable."""
    if size * 0.001 > MAX_EXTENT:
        return f"check its units{' and user_scale' if user else ''}, or set normalize_size"
    fix = "set user_scale: 0.001 (`--user-scale 0.001`; centimetres: 0.01)" if user else "scale it by 0.001"
    return f"if its units are millimetres, {fix}, or set normalize_size"
