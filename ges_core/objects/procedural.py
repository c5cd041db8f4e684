"""Procedural objects: seeded random dimensions in named categories, built with trimesh.

Every builder returns a :class:`Shape` already in its resting pose (bottom on z = 0, upright as a
person would set it down) in metres. Dimensions are drawn so that the object fits a human hand:
4-12 cm across in at least one grasp direction. Same seed → same numbers → byte-identical meshes.

Collision, by kind:

- ``primitive``: exact :class:`PrimitiveShape` set (box, cube, plate, can, sphere, capsule, L-bracket);
- ``convex``: the mesh is its own convex hull, used as one convex part (cone, wedge, ellipsoid);
- ``concave``: needs a CoACD decomposition (mug, bowl, bottle, torus).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from ges_core.objects.asset import PrimitiveShape

__all__ = ["CATEGORIES", "Shape", "build_shape", "shape_seed"]

SECTIONS = 48
"""Facets around a round shape: the polygon's volume is 99.7 % of the true solid's, close enough that
the exact primitive collision and the visual mesh agree to well under 1 %."""

X_TO_Z = (np.sqrt(0.5), 0.0, -np.sqrt(0.5), 0.0)
"""wxyz quaternion turning a primitive's local x axis (capsule/cylinder axis in SAPIEN) onto world z."""


@dataclass(frozen=True, kw_only=True)
class Shape:
    """One procedural object in its resting pose, metres."""

    mesh: trimesh.Trimesh
    kind: Literal["primitive", "convex", "concave"]
    primitives: tuple[PrimitiveShape, ...] = ()
    """Exact collision when ``kind == "primitive"``, in the mesh's frame."""
    params: dict[str, float] | None = None
    """The drawn dimensions (m), for reports."""


def shape_seed(seed: int, category: str, index: int) -> np.random.Generator:
    """Generator for object ``index`` of ``category``; independent of the other categories and of the
    order in which objects are built (crc32 of the name, not Python's salted ``hash``)."""
    return np.random.default_rng([seed, zlib.crc32(category.encode()), index])


def build_shape(category: str, rng: np.random.Generator) -> Shape:
    """Build one object of ``category`` with dimensions drawn from ``rng``."""
    return CATEGORIES[category](rng)


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.round(rng.uniform(lo, hi), 4))  # 0.1 mm grid: readable params, exact repeats


def _pose(xyz, quat=(1.0, 0.0, 0.0, 0.0)) -> tuple[float, ...]:
    return tuple(float(v) for v in (*xyz, *quat))


def _box_at(extents, center) -> tuple[trimesh.Trimesh, PrimitiveShape]:
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(center)
    prim = PrimitiveShape(kind="box", size=tuple(float(e) / 2 for e in extents), pose=_pose(center))
    return mesh, prim


def _box_shape(ext: tuple[float, float, float], params: dict[str, float]) -> Shape:
    mesh, prim = _box_at(ext, (0.0, 0.0, ext[2] / 2))
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=params)


def box(rng: np.random.Generator) -> Shape:
    """Rectangular block; the narrowest side (4-8 cm) is the grasp width."""
    p = {"width": _u(rng, 0.04, 0.08), "length": _u(rng, 0.06, 0.12), "height": _u(rng, 0.04, 0.10)}
    return _box_shape((p["length"], p["width"], p["height"]), p)


def cube(rng: np.random.Generator) -> Shape:
    """Cube of side 4-8 cm."""
    p = {"side": _u(rng, 0.04, 0.08)}
    return _box_shape((p["side"],) * 3, p)


def plate(rng: np.random.Generator) -> Shape:
    """Flat plate (a tile or book-like slab), 1-2.5 cm thick, lying flat."""
    p = {"length": _u(rng, 0.08, 0.14), "width": _u(rng, 0.06, 0.10), "thickness": _u(rng, 0.01, 0.025)}
    return _box_shape((p["length"], p["width"], p["thickness"]), p)


def can(rng: np.random.Generator) -> Shape:
    """Standing cylinder, 5-9 cm in diameter."""
    p = {"radius": _u(rng, 0.025, 0.045), "height": _u(rng, 0.06, 0.14)}
    mesh = trimesh.creation.cylinder(radius=p["radius"], height=p["height"], sections=SECTIONS)
    mesh.apply_translation((0.0, 0.0, p["height"] / 2))
    prim = PrimitiveShape(
        kind="cylinder", size=(p["radius"], p["height"] / 2), pose=_pose((0, 0, p["height"] / 2), X_TO_Z)
    )
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=p)


def sphere(rng: np.random.Generator) -> Shape:
    """Ball, 5-9 cm in diameter."""
    p = {"radius": _u(rng, 0.025, 0.045)}
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=p["radius"])
    mesh.apply_translation((0.0, 0.0, p["radius"]))
    prim = PrimitiveShape(kind="sphere", size=(p["radius"],), pose=_pose((0, 0, p["radius"])))
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=p)


def capsule(rng: np.random.Generator) -> Shape:
    """Capsule lying along x (a capsule on its end is unstable), 4-7 cm in diameter."""
    p = {"radius": _u(rng, 0.02, 0.035), "length": _u(rng, 0.04, 0.08)}
    mesh = trimesh.creation.capsule(height=p["length"], radius=p["radius"], count=[SECTIONS, SECTIONS // 2])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))  # z axis → x axis
    mesh.apply_translation((0.0, 0.0, p["radius"]))
    prim = PrimitiveShape(kind="capsule", size=(p["radius"], p["length"] / 2), pose=_pose((0, 0, p["radius"])))
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=p)


def l_bracket(rng: np.random.Generator) -> Shape:
    """L-shaped bracket: a base slab and an upright slab, 1.5-2.5 cm thick, as two exact boxes."""
    p = {
        "width": _u(rng, 0.04, 0.08),
        "base": _u(rng, 0.06, 0.12),
        "height": _u(rng, 0.06, 0.12),
        "thickness": _u(rng, 0.015, 0.025),
    }
    a, w, h, t = p["base"], p["width"], p["height"], p["thickness"]
    outline = np.array([[0, 0], [a, 0], [a, t], [t, t], [t, h], [0, h]]) - [a / 2, 0]
    mesh = _extrude_star_polygon(outline, w)
    _, base = _box_at((a, w, t), (0.0, 0.0, t / 2))
    _, upright = _box_at((t, w, h - t), (t / 2 - a / 2, 0.0, t + (h - t) / 2))
    return Shape(mesh=mesh, kind="primitive", primitives=(base, upright), params=p)


def _extrude_star_polygon(outline: np.ndarray, width: float) -> trimesh.Trimesh:
    """Prism of an (n, 2) counter-clockwise x-z outline, star-shaped from vertex 0, extruded along y
    over ``[-width/2, width/2]``; watertight, one body."""
    n = len(outline)
    front = np.column_stack([outline[:, 0], np.full(n, -width / 2), outline[:, 1]])
    back = front + [0.0, width, 0.0]
    fan = np.array([[0, i, i + 1] for i in range(1, n - 1)])
    sides = [[i, (i + 1) % n, n + (i + 1) % n] for i in range(n)] + [[i, n + (i + 1) % n, n + i] for i in range(n)]
    faces = np.vstack([fan, fan[:, ::-1] + n, np.array(sides)])
    mesh = trimesh.Trimesh(np.vstack([front, back]), faces, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def wedge(rng: np.random.Generator) -> Shape:
    """Right-triangle prism (door stop), convex."""
    p = {"length": _u(rng, 0.06, 0.12), "width": _u(rng, 0.04, 0.08), "height": _u(rng, 0.04, 0.08)}
    outline = np.array([[0.0, 0.0], [p["length"], 0.0], [0.0, p["height"]]]) - [p["length"] / 3, 0.0]
    return Shape(mesh=_extrude_star_polygon(outline, p["width"]), kind="convex", params=p)


def cone(rng: np.random.Generator) -> Shape:
    """Cone standing on its base, convex."""
    p = {"radius": _u(rng, 0.03, 0.05), "height": _u(rng, 0.06, 0.12)}
    mesh = trimesh.creation.cone(radius=p["radius"], height=p["height"], sections=SECTIONS)
    return Shape(mesh=mesh, kind="convex", params=p)


def ellipsoid(rng: np.random.Generator) -> Shape:
    """Ellipsoid with its shortest axis vertical (its most stable pose), convex."""
    axes = sorted((_u(rng, 0.025, 0.05) for _ in range(3)), reverse=True)
    p = {"a": axes[0], "b": axes[1], "c": axes[2]}
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mesh.apply_scale(axes)
    mesh.apply_translation((0.0, 0.0, axes[2]))
    return Shape(mesh=mesh, kind="convex", params=p)


def _revolve(profile: list[tuple[float, float]]) -> trimesh.Trimesh:
    """Solid of revolution of a closed (r, z) profile starting and ending on the axis; a face (not an
    edge) faces +x so that parts attached there sit flat against it."""
    mesh = trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=SECTIONS)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / SECTIONS, (0, 0, 1)))
    return mesh


def bottle(rng: np.random.Generator) -> Shape:
    """Solid bottle: body, conical shoulder and narrow neck (concave at the neck)."""
    p = {
        "radius": _u(rng, 0.025, 0.04),
        "body": _u(rng, 0.08, 0.14),
        "shoulder": _u(rng, 0.02, 0.035),
        "neck_radius": _u(rng, 0.01, 0.015),
        "neck": _u(rng, 0.02, 0.04),
    }
    z1 = p["body"]
    z2 = z1 + p["shoulder"]
    z3 = z2 + p["neck"]
    r, rn = p["radius"], p["neck_radius"]
    mesh = _revolve([(0, 0), (r, 0), (r, z1), (rn, z2), (rn, z3), (0, z3)])
    return Shape(mesh=mesh, kind="concave", params=p)


def bowl(rng: np.random.Generator) -> Shape:
    """Open bowl with a flared wall 4-6 mm thick."""
    p = {
        "radius": _u(rng, 0.05, 0.075),
        "height": _u(rng, 0.04, 0.07),
        "base_radius": _u(rng, 0.025, 0.035),
        "wall": _u(rng, 0.004, 0.006),
    }
    r0, r1, h, w = p["base_radius"], p["radius"], p["height"], p["wall"]
    s = np.linspace(0.0, 1.0, 9)
    outer = [(r0 + (r1 - r0) * np.sqrt(t), h * t) for t in s]
    inner = [(r - w, z) for r, z in outer[::-1] if z >= w] + [(r0 - w, w)]
    mesh = _revolve([(0.0, 0.0), *outer, *inner, (0.0, w)])
    return Shape(mesh=mesh, kind="concave", params=p)


def mug(rng: np.random.Generator) -> Shape:
    """Mug: an open cylindrical cup (4-5 mm wall) with a round handle touching its wall flat."""
    p = {
        "radius": _u(rng, 0.035, 0.045),
        "height": _u(rng, 0.08, 0.11),
        "wall": _u(rng, 0.004, 0.005),
        "handle_radius": _u(rng, 0.022, 0.03),
        "handle_thickness": _u(rng, 0.005, 0.007),
    }
    r, h, w = p["radius"], p["height"], p["wall"]
    cup = _revolve([(0, 0), (r, 0), (r, h), (r - w, h), (r - w, 1.5 * w), (0, 1.5 * w)])
    wall_x = r * np.cos(np.pi / SECTIONS)  # the flat face of the polygonal wall facing +x
    handle = _half_tube(p["handle_radius"], p["handle_thickness"], (wall_x, 0.0, h / 2))
    return Shape(mesh=trimesh.util.concatenate([cup, handle]), kind="concave", params=p)


def _half_tube(arc_radius: float, tube_radius: float, start: tuple[float, float, float]) -> trimesh.Trimesh:
    """Closed half-torus in the x-z plane bulging toward +x, its two flat end caps on the plane
    x = start[0] (facing -x), centred at start[2] ± arc_radius."""
    n_arc, n_tube = 24, 16
    phi = np.linspace(-np.pi / 2, np.pi / 2, n_arc + 1)
    theta = np.linspace(0.0, 2 * np.pi, n_tube, endpoint=False)
    radial = np.stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=1)  # (n_arc+1, 3)
    centres = np.asarray(start) + arc_radius * radial
    ring = np.cos(theta)[None, :, None] * radial[:, None, :] + np.sin(theta)[None, :, None] * [0.0, 1.0, 0.0]
    vertices = (centres[:, None, :] + tube_radius * ring).reshape(-1, 3)
    idx = np.arange((n_arc + 1) * n_tube).reshape(n_arc + 1, n_tube)
    a, b = idx[:-1], idx[1:]
    a2, b2 = np.roll(a, -1, axis=1), np.roll(b, -1, axis=1)
    faces = np.vstack([np.stack([a, b, b2], -1).reshape(-1, 3), np.stack([a, b2, a2], -1).reshape(-1, 3)])
    caps = [_cap(idx[0], len(vertices)), _cap(idx[-1], len(vertices) + 1)]
    vertices = np.vstack([vertices, centres[0], centres[-1]])
    mesh = trimesh.Trimesh(vertices, np.vstack([faces, *caps]), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _cap(ring: np.ndarray, centre: int) -> np.ndarray:
    return np.stack([np.full(len(ring), centre), ring, np.roll(ring, -1)], axis=1)


def torus(rng: np.random.Generator) -> Shape:
    """Ring lying flat, 7-10 cm across, tube 2-3.6 cm thick."""
    p = {"major_radius": _u(rng, 0.035, 0.05), "minor_radius": _u(rng, 0.01, 0.018)}
    mesh = trimesh.creation.torus(
        major_radius=p["major_radius"], minor_radius=p["minor_radius"], major_sections=SECTIONS, minor_sections=16
    )
    mesh.apply_translation((0.0, 0.0, p["minor_radius"]))
    return Shape(mesh=mesh, kind="concave", params=p)


CATEGORIES: dict[str, Callable[[np.random.Generator], Shape]] = {
    "box": box,
    "cube": cube,
    "plate": plate,
    "can": can,
    "sphere": sphere,
    "capsule": capsule,
    "l_bracket": l_bracket,
    "wedge": wedge,
    "cone": cone,
    "ellipsoid": ellipsoid,
    "bottle": bottle,
    "bowl": bowl,
    "mug": mug,
    "torus": torus,
}
"""Category name → builder, in listing order."""
