"""Procedural objects: seeded random dimensions in named categories, built with trimesh.

Every builder returns a :class:`Shape` already in its resting pose (bottom on z = 0, upright as a
person would set it down) in metres. Dimensions are drawn so that the object fits a human hand:
4-12 cm across in at least one grasp direction. Same seed → same numbers → byte-identical meshes.

Collision, by kind:

- ``primitive``: exact :class:`PrimitiveShape` set (box, cube, plate, can, sphere, capsule, L-bracket,
  hammer, dumbbell, rod, spray can, puck, remote);
- ``convex``: the mesh is its own convex hull, used as one convex part (cone, wedge, ellipsoid, hexagonal
  prism, pyramid, triangular prism, frustum);
- ``concave``: needs a CoACD decomposition (mug, bowl, bottle, torus).

The categories after ``torus`` were added for the whole-library dataset (more categories for the
unseen-category split; thin handles and compound shapes the first fourteen lack); they are appended so
that the earlier categories' objects and listing order are unchanged.

The last four (:data:`HELD_OUT_CATEGORIES`: stamp, cross, barrel, channel) were added to give the
unseen-category split enough objects to tell two policies apart (two categories, 20 objects, were too few);
the library holds them out by default (``LibraryConfig.held_out_categories``), so adding them moved no
other object's split.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from ges_core.objects.asset import PrimitiveShape

__all__ = ["CATEGORIES", "HELD_OUT_CATEGORIES", "Shape", "build_shape", "shape_seed"]

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


def _standing_cylinder(p: dict[str, float]) -> Shape:
    """Cylinder of ``p["radius"]`` and ``p["height"]`` (m) standing on its base at z = 0 (one exact primitive)."""
    mesh = trimesh.creation.cylinder(radius=p["radius"], height=p["height"], sections=SECTIONS)
    mesh.apply_translation((0.0, 0.0, p["height"] / 2))
    prim = PrimitiveShape(
        kind="cylinder", size=(p["radius"], p["height"] / 2), pose=_pose((0, 0, p["height"] / 2), X_TO_Z)
    )
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=p)


def can(rng: np.random.Generator) -> Shape:
    """Standing cylinder, 5-9 cm in diameter."""
    p = {"radius": _u(rng, 0.025, 0.045), "height": _u(rng, 0.06, 0.14)}
    return _standing_cylinder(p)


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
    fan = np.array([[0, i, i + 1] for i in range(1, len(outline) - 1)])
    return _extrude_triangulated(outline, fan, width)


def _extrude_triangulated(outline: np.ndarray, caps: np.ndarray, width: float) -> trimesh.Trimesh:
    """Prism of an (n, 2) counter-clockwise x-z outline whose face is given as (m, 3) triangles of its
    vertices (any simple polygon), extruded along y over ``[-width/2, width/2]``; watertight, one body."""
    n = len(outline)
    front = np.column_stack([outline[:, 0], np.full(n, -width / 2), outline[:, 1]])
    back = front + [0.0, width, 0.0]
    sides = [[i, (i + 1) % n, n + (i + 1) % n] for i in range(n)] + [[i, n + (i + 1) % n, n + i] for i in range(n)]
    faces = np.vstack([caps, caps[:, ::-1] + n, np.array(sides)])
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


def _extrude_around(outline: np.ndarray, centre: tuple[float, float], width: float) -> trimesh.Trimesh:
    """Prism of an (n, 2) counter-clockwise x-z outline that is star-shaped from the interior point
    ``centre`` (caps fanned around it, so the outline need not be star-shaped from a vertex), extruded
    along y over ``[-width/2, width/2]``; watertight, one body."""
    n = len(outline)
    ring = np.vstack([outline, centre])
    front = np.column_stack([ring[:, 0], np.full(n + 1, -width / 2), ring[:, 1]])
    back = front + [0.0, width, 0.0]
    fan = np.array([[n, i, (i + 1) % n] for i in range(n)])
    sides = [[i, (i + 1) % n, n + 1 + (i + 1) % n] for i in range(n)] + [
        [i, n + 1 + (i + 1) % n, n + 1 + i] for i in range(n)
    ]
    faces = np.vstack([fan, fan[:, ::-1] + n + 1, np.array(sides)])
    mesh = trimesh.Trimesh(np.vstack([front, back]), faces, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _lying(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` turned +90 degrees about x (its y axis onto z): an x-z outline extruded along y lies flat."""
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    mesh.apply_translation((0.0, 0.0, -mesh.bounds[0, 2]))
    return mesh


def hammer(rng: np.random.Generator) -> Shape:
    """Hammer-like T lying flat: a 2.5-3.5 cm square handle and a head across its end (two exact boxes).

    The thin-handle case of Stage 1: the hand must close on the handle, not across the whole T."""
    p = {
        "handle_length": _u(rng, 0.10, 0.14),
        "handle_width": _u(rng, 0.025, 0.035),
        "head_length": _u(rng, 0.07, 0.10),
        "head_width": _u(rng, 0.025, 0.035),
    }
    length, hw, head, hd = p["handle_length"], p["handle_width"], p["head_length"], p["head_width"]
    thickness = hw  # a square handle; the head is as thick as the handle
    x0, x1 = -(length + hd) / 2, (length + hd) / 2 - hd  # handle from x0 to x1, head from x1 to x1 + hd
    outline = np.array(
        [
            [x0, -hw / 2],
            [x1, -hw / 2],
            [x1, -head / 2],
            [x1 + hd, -head / 2],
            [x1 + hd, head / 2],
            [x1, head / 2],
            [x1, hw / 2],
            [x0, hw / 2],
        ]
    )  # x-z outline, counter-clockwise
    mesh = _lying(_extrude_around(outline, (x1 + hd / 2, 0.0), thickness))
    _, handle = _box_at((length, hw, thickness), ((x0 + x1) / 2, 0.0, thickness / 2))
    _, top = _box_at((hd, head, thickness), (x1 + hd / 2, 0.0, thickness / 2))
    return Shape(mesh=mesh, kind="primitive", primitives=(handle, top), params=p)


def _cylinder_x(radius: float, x0: float, x1: float, z: float) -> PrimitiveShape:
    """A cylinder primitive along x from ``x0`` to ``x1`` at height ``z`` (its axis)."""
    return PrimitiveShape(kind="cylinder", size=(radius, (x1 - x0) / 2), pose=_pose(((x0 + x1) / 2, 0.0, z)))


def _revolve_x(profile: list[tuple[float, float]]) -> trimesh.Trimesh:
    """:func:`_revolve` of an (r, s) profile turned so its axis runs along x, centred at x = 0, resting on z = 0."""
    mesh = _revolve(profile)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))  # z axis -> x axis
    mesh.apply_translation((-mesh.bounds[:, 0].mean(), 0.0, -mesh.bounds[0, 2]))
    return mesh


def dumbbell(rng: np.random.Generator) -> Shape:
    """Dumbbell lying on its two weights: a 2.4-3.6 cm handle between two discs (three exact cylinders)."""
    p = {
        "weight_radius": _u(rng, 0.03, 0.04),
        "weight_length": _u(rng, 0.02, 0.035),
        "handle_radius": _u(rng, 0.012, 0.018),
        "handle_length": _u(rng, 0.08, 0.11),
    }
    rw, lw, rh, lh = p["weight_radius"], p["weight_length"], p["handle_radius"], p["handle_length"]
    profile = [(0, 0), (rw, 0), (rw, lw), (rh, lw), (rh, lw + lh), (rw, lw + lh), (rw, 2 * lw + lh), (0, 2 * lw + lh)]
    mesh = _revolve_x(profile)
    half = lw + lh / 2
    z = mesh.bounds[1, 2] / 2  # the axis: halfway up (the weights are the widest part)
    prims = (
        _cylinder_x(rw, -half, -half + lw, z),
        _cylinder_x(rh, -half + lw, half - lw, z),
        _cylinder_x(rw, half - lw, half, z),
    )
    return Shape(mesh=mesh, kind="primitive", primitives=prims, params=p)


def rod(rng: np.random.Generator) -> Shape:
    """Thin rod lying along x (a broom handle, a rolling pin), 2-3.5 cm in diameter, 12-18 cm long."""
    p = {"radius": _u(rng, 0.01, 0.0175), "length": _u(rng, 0.12, 0.18)}
    mesh = _revolve_x([(0, 0), (p["radius"], 0), (p["radius"], p["length"]), (0, p["length"])])
    z = mesh.bounds[1, 2] / 2
    prim = _cylinder_x(p["radius"], -p["length"] / 2, p["length"] / 2, z)
    return Shape(mesh=mesh, kind="primitive", primitives=(prim,), params=p)


def spray_can(rng: np.random.Generator) -> Shape:
    """Standing can with a narrower cap on top (two exact cylinders)."""
    p = {
        "radius": _u(rng, 0.025, 0.035),
        "height": _u(rng, 0.10, 0.15),
        "cap_ratio": _u(rng, 0.6, 0.8),
        "cap_height": _u(rng, 0.02, 0.03),
    }
    return _stacked_cylinders(p["radius"], p["height"], p["radius"] * p["cap_ratio"], p["cap_height"], p)


def _stacked_cylinders(r: float, h: float, r_top: float, h_top: float, params: dict[str, float]) -> Shape:
    """A standing cylinder (radius ``r``, height ``h``, m) with another (``r_top``, ``h_top``) on top of it: the
    revolved mesh and the two exact cylinders."""
    mesh = _revolve([(0, 0), (r, 0), (r, h), (r_top, h), (r_top, h + h_top), (0, h + h_top)])
    low = PrimitiveShape(kind="cylinder", size=(r, h / 2), pose=_pose((0, 0, h / 2), X_TO_Z))
    top = PrimitiveShape(kind="cylinder", size=(r_top, h_top / 2), pose=_pose((0, 0, h + h_top / 2), X_TO_Z))
    return Shape(mesh=mesh, kind="primitive", primitives=(low, top), params=params)


def puck(rng: np.random.Generator) -> Shape:
    """Short wide disc lying flat (a jar lid, a hockey puck), 6-10 cm across, 1.5-3 cm tall."""
    p = {"radius": _u(rng, 0.03, 0.05), "height": _u(rng, 0.015, 0.03)}
    return _standing_cylinder(p)


def remote(rng: np.random.Generator) -> Shape:
    """Long flat bar lying flat (a remote control, a phone), 14-19 cm long."""
    p = {"length": _u(rng, 0.14, 0.19), "width": _u(rng, 0.04, 0.055), "thickness": _u(rng, 0.015, 0.025)}
    return _box_shape((p["length"], p["width"], p["thickness"]), p)


def hex_prism(rng: np.random.Generator) -> Shape:
    """Standing hexagonal prism (a nut, a pencil holder), convex."""
    p = {"radius": _u(rng, 0.025, 0.04), "height": _u(rng, 0.05, 0.12)}
    mesh = trimesh.creation.cylinder(radius=p["radius"], height=p["height"], sections=6)
    mesh.apply_translation((0.0, 0.0, p["height"] / 2))
    return Shape(mesh=mesh, kind="convex", params=p)


def pyramid(rng: np.random.Generator) -> Shape:
    """Square pyramid on its base, convex."""
    p = {"base": _u(rng, 0.05, 0.09), "height": _u(rng, 0.05, 0.09)}
    b = p["base"] / 2
    corners = [(-b, -b, 0.0), (b, -b, 0.0), (b, b, 0.0), (-b, b, 0.0), (0.0, 0.0, p["height"])]
    return Shape(mesh=trimesh.Trimesh(corners).convex_hull, kind="convex", params=p)


def tri_prism(rng: np.random.Generator) -> Shape:
    """Equilateral triangular prism lying on a side face (a chocolate bar box), convex."""
    p = {"side": _u(rng, 0.04, 0.07), "length": _u(rng, 0.08, 0.14)}
    s = p["side"]
    outline = np.array([[-s / 2, 0.0], [s / 2, 0.0], [0.0, s * np.sqrt(3) / 2]])
    return Shape(mesh=_extrude_star_polygon(outline, p["length"]), kind="convex", params=p)


def frustum(rng: np.random.Generator) -> Shape:
    """Truncated cone standing on its narrow end (a tumbler, a flower pot), convex."""
    p = {"bottom_radius": _u(rng, 0.025, 0.035), "top_radius": _u(rng, 0.035, 0.05), "height": _u(rng, 0.07, 0.12)}
    mesh = _revolve([(0, 0), (p["bottom_radius"], 0), (p["top_radius"], p["height"]), (0, p["height"])])
    return Shape(mesh=mesh, kind="convex", params=p)


def stamp(rng: np.random.Generator) -> Shape:
    """A wide short disc with an upright round handle on it (a rubber stamp, a lid with a knob): two exact
    cylinders; the handle, 2.4-4 cm thick, is what a hand closes on."""
    p = {
        "base_radius": _u(rng, 0.035, 0.05),
        "base_height": _u(rng, 0.01, 0.02),
        "handle_radius": _u(rng, 0.012, 0.02),
        "handle_height": _u(rng, 0.04, 0.07),
    }
    return _stacked_cylinders(p["base_radius"], p["base_height"], p["handle_radius"], p["handle_height"], p)


def cross(rng: np.random.Generator) -> Shape:
    """Plus-shaped slab lying flat: two crossed bars 2.5-3.5 cm wide, 8-12 cm long (three exact boxes)."""
    p = {"span": _u(rng, 0.08, 0.12), "arm_width": _u(rng, 0.025, 0.035), "thickness": _u(rng, 0.02, 0.03)}
    a, w, t = p["span"] / 2, p["arm_width"] / 2, p["thickness"]
    outline = np.array(
        [[-a, -w], [-w, -w], [-w, -a], [w, -a], [w, -w], [a, -w], [a, w], [w, w], [w, a], [-w, a], [-w, w], [-a, w]]
    )  # x-z outline, counter-clockwise, star-shaped from the centre
    mesh = _lying(_extrude_around(outline, (0.0, 0.0), t))
    _, along_x = _box_at((2 * a, 2 * w, t), (0.0, 0.0, t / 2))  # the arms along y abut it: no volume twice
    _, front = _box_at((2 * w, a - w, t), (0.0, -(a + w) / 2, t / 2))
    _, back = _box_at((2 * w, a - w, t), (0.0, (a + w) / 2, t / 2))
    return Shape(mesh=mesh, kind="primitive", primitives=(along_x, front, back), params=p)


def barrel(rng: np.random.Generator) -> Shape:
    """Standing barrel: a cylinder whose radius bulges 0.4-1 cm at mid-height (a sine profile), convex."""
    p = {"end_radius": _u(rng, 0.025, 0.035), "bulge": _u(rng, 0.004, 0.01), "height": _u(rng, 0.07, 0.12)}
    z = np.linspace(0.0, p["height"], 9)
    r = p["end_radius"] + p["bulge"] * np.sin(np.pi * z / p["height"])
    mesh = _revolve([(0.0, 0.0), *zip(r.tolist(), z.tolist(), strict=True), (0.0, p["height"])])
    return Shape(mesh=mesh, kind="convex", params=p)


def channel(rng: np.random.Generator) -> Shape:
    """U channel lying open side up (a trough, a cable duct): a base and two walls 6-10 mm thick, 5-8 cm
    across, 8-14 cm long (three exact boxes)."""
    p = {
        "width": _u(rng, 0.05, 0.08),
        "height": _u(rng, 0.03, 0.05),
        "length": _u(rng, 0.08, 0.14),
        "thickness": _u(rng, 0.006, 0.01),
    }
    w, h, length, t = p["width"] / 2, p["height"], p["length"], p["thickness"]
    outline = np.array([[-w, 0], [w, 0], [w, h], [w - t, h], [w - t, t], [-w + t, t], [-w + t, h], [-w, h]])
    caps = np.array([[0, 1, 4], [0, 4, 5], [1, 2, 3], [1, 3, 4], [5, 6, 7], [5, 7, 0]])  # base, right, left wall
    mesh = _extrude_triangulated(outline, caps, length)
    _, base = _box_at((2 * w, length, t), (0.0, 0.0, t / 2))
    _, right = _box_at((t, length, h - t), (w - t / 2, 0.0, t + (h - t) / 2))
    _, left = _box_at((t, length, h - t), (-w + t / 2, 0.0, t + (h - t) / 2))
    return Shape(mesh=mesh, kind="primitive", primitives=(base, right, left), params=p)


HELD_OUT_CATEGORIES = ("stamp", "cross", "barrel", "channel")
"""Categories the library holds out as unseen categories by default (``LibraryConfig.held_out_categories``)."""

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
    "hammer": hammer,
    "dumbbell": dumbbell,
    "rod": rod,
    "spray_can": spray_can,
    "puck": puck,
    "remote": remote,
    "hex_prism": hex_prism,
    "pyramid": pyramid,
    "tri_prism": tri_prism,
    "frustum": frustum,
    "stamp": stamp,
    "cross": cross,
    "barrel": barrel,
    "channel": channel,
}
"""Category name → builder, in listing order."""
