"""Procedural objects: determinism, watertightness, collision fidelity, hand size, resting pose."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.objects.asset import ConvexPart, PrimitiveShape
from ges_core.objects.decompose import mesh_to_obj_bytes
from ges_core.objects.placement import support_margin
from ges_core.objects.procedural import CATEGORIES, build_shape, shape_seed
from ges_core.objects.processing import collision_shapes, process_entry
from ges_core.objects.sources import list_procedural

NON_CONCAVE = [c for c in CATEGORIES if build_shape(c, shape_seed(0, c, 0)).kind != "concave"]


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))


def primitive_mesh(prim: PrimitiveShape) -> trimesh.Trimesh:
    """An independent trimesh of a PrimitiveShape, following asset.py's conventions (axis along x)."""
    if prim.kind == "box":
        mesh = trimesh.creation.box(extents=2 * np.asarray(prim.size))
    elif prim.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=4, radius=prim.size[0])
    elif prim.kind == "capsule":
        mesh = trimesh.creation.capsule(height=2 * prim.size[1], radius=prim.size[0], count=[64, 32])
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    else:
        mesh = trimesh.creation.cylinder(radius=prim.size[0], height=2 * prim.size[1], sections=128)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    w, x, y, z = prim.pose[3:]
    transform = trimesh.transformations.quaternion_matrix([w, x, y, z])
    transform[:3, 3] = prim.pose[:3]
    mesh.apply_transform(transform)
    return mesh


def primitive_volume(prim: PrimitiveShape) -> float:
    """Closed-form volume (m^3)."""
    s = prim.size
    return {
        "box": lambda: 8 * s[0] * s[1] * s[2],
        "sphere": lambda: 4 / 3 * np.pi * s[0] ** 3,
        "capsule": lambda: np.pi * s[0] ** 2 * 2 * s[1] + 4 / 3 * np.pi * s[0] ** 3,
        "cylinder": lambda: np.pi * s[0] ** 2 * 2 * s[1],
    }[prim.kind]()


@pytest.mark.parametrize("category", list(CATEGORIES))
def test_same_seed_same_bytes_different_seed_different(category):
    first = mesh_to_obj_bytes(build_shape(category, shape_seed(3, category, 5)).mesh)
    again = mesh_to_obj_bytes(build_shape(category, shape_seed(3, category, 5)).mesh)
    other_seed = mesh_to_obj_bytes(build_shape(category, shape_seed(4, category, 5)).mesh)
    other_index = mesh_to_obj_bytes(build_shape(category, shape_seed(3, category, 6)).mesh)
    assert first == again
    assert first != other_seed and first != other_index


def test_processed_mesh_hash_and_ids_are_stable():
    a = [process_entry(e).mesh_hash for e in list_procedural(count=2, seed=7, categories=("mug", "box"))]
    b = [process_entry(e).mesh_hash for e in list_procedural(count=2, seed=7, categories=("mug", "box"))]
    c = [process_entry(e).mesh_hash for e in list_procedural(count=2, seed=8, categories=("mug", "box"))]
    assert a == b and len(set(a)) == 4
    assert not set(a) & set(c)
    ids = [e.object_id for e in list_procedural(count=2, seed=7, categories=("mug",))]
    assert ids == ["procedural/mug/000", "procedural/mug/001"]


@pytest.mark.parametrize("category", list(CATEGORIES))
def test_watertight_positive_volume_hand_sized_and_resting(category):
    for entry in list_procedural(count=3, seed=1, categories=(category,)):
        obj = process_entry(entry)
        mesh = obj.mesh
        assert mesh.is_watertight and mesh.is_winding_consistent and obj.volume > 0
        assert abs(mesh.bounds[0, 2]) < 1e-9  # lowest point on the table
        assert np.allclose(mesh.center_mass[:2], 0.0, atol=1e-9)
        assert support_margin(mesh) > -1e-4, "centre of mass outside the support polygon: not at rest"
        assert min(mesh.extents) >= 0.01 and max(mesh.extents) <= 0.20
        grasp_width = obj.mesh.convex_hull.extents.min()
        assert 0.01 <= grasp_width <= 0.12, f"{entry.object_id} narrowest side {grasp_width:.3f} m"


@pytest.mark.parametrize("category", NON_CONCAVE)
def test_collision_volume_matches_mesh_volume(category):
    obj = process_entry(list_procedural(count=1, seed=2, categories=(category,))[0])
    shapes = collision_shapes(obj, settings=None, compute=False)
    if obj.kind == "primitive":
        assert all(isinstance(s, PrimitiveShape) for s in shapes)
        volume = sum(primitive_volume(s) for s in shapes)
    else:
        assert len(shapes) == 1 and isinstance(shapes[0], ConvexPart)
        volume = trimesh.load(shapes[0].path, force="mesh").volume
    assert volume == pytest.approx(obj.volume, rel=0.02)


PRIMITIVE_SETS = ("box", "can", "sphere", "capsule", "l_bracket", "hammer", "dumbbell", "rod", "spray_can", "puck")


@pytest.mark.parametrize("category", [c for c in NON_CONCAVE if c in PRIMITIVE_SETS])
def test_primitives_sit_where_the_mesh_is(category):
    """Primitive poses (axis conventions, placement shift) agree with the visual mesh: the union of
    the primitives' own meshes has the mesh's bounds, and mesh vertices lie on the primitives."""
    obj = process_entry(list_procedural(count=1, seed=4, categories=(category,))[0])
    prims = [primitive_mesh(p) for p in obj.primitives]
    union_bounds = np.array([[m.bounds[0] for m in prims], [m.bounds[1] for m in prims]])
    assert np.allclose(union_bounds[0].min(0), obj.mesh.bounds[0], atol=1e-3)
    assert np.allclose(union_bounds[1].max(0), obj.mesh.bounds[1], atol=1e-3)
    dist = np.min([np.abs(trimesh.proximity.signed_distance(m, obj.mesh.vertices)) for m in prims], axis=0)
    assert dist.max() < 1e-3


def test_concave_categories_need_decomposition():
    kinds = {c: build_shape(c, shape_seed(0, c, 0)).kind for c in CATEGORIES}
    assert {c for c, k in kinds.items() if k == "concave"} == {"mug", "bowl", "bottle", "torus"}
    for category in ("mug", "bowl", "bottle", "torus"):
        mesh = build_shape(category, shape_seed(0, category, 0)).mesh
        assert mesh.volume < 0.95 * mesh.convex_hull.volume


def test_at_least_twelve_categories():
    assert len(CATEGORIES) >= 12
