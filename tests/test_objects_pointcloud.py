"""Surface point clouds: count, on-surface, unit outward normals, seeding, farthest-point coverage."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from ges_core.errors import AssetError
from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.objects.pointcloud import farthest_point_indices, sample_surface

IDS = [
    "procedural/box/000",
    "procedural/mug/000",  # two touching bodies: cup and handle
    "procedural/torus/000",
    "pybullet/random_urdfs/042",  # eight convex bodies glued face to face
    "pybullet/classic/teddy",  # fifteen overlapping convex hulls
]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GES_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield ObjectLibrary(LibraryConfig(procedural_count=1))


def outside(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(n,) bool: outside every body of ``mesh`` (ray parity per body: robust to touching bodies)."""
    out = np.ones(len(points), dtype=bool)
    for body in mesh.split(only_watertight=False):
        out &= ~body.contains(points)
    return out


def on_surface(mesh: trimesh.Trimesh, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """(n,) bool: each point lies in the plane and inside the edges of some face. (Exact, unlike
    ``trimesh.proximity.closest_point``, which misses by 0.2 mm on some of teddy's sliver faces.)"""
    found = np.zeros(len(points), dtype=bool)
    for i, p in enumerate(points):
        tri = mesh.triangles
        in_plane = np.abs(np.einsum("ij,ij->i", p - tri[:, 0], mesh.face_normals)) < tol
        bary = trimesh.triangles.points_to_barycentric(tri[in_plane], np.repeat(p[None], in_plane.sum(), 0))
        found[i] = bool((bary >= -1e-6).all(axis=1).any())
    return found


@pytest.mark.parametrize("object_id", IDS)
def test_points_on_surface_with_unit_outward_normals(library, object_id):
    mesh = library.processed(object_id).mesh
    points, normals = library.point_cloud(object_id, 600, seed=1)
    assert points.shape == (600, 3) and normals.shape == (600, 3)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    assert on_surface(mesh, points).all()
    eps = 1e-5  # m: beyond float noise, inside any real feature
    assert outside(mesh, points + eps * normals).all(), "a normal points inward or a point is hidden"
    assert not outside(mesh, points - eps * normals).all()


def test_hidden_faces_of_touching_bodies_are_not_sampled(library):
    """Teddy's hulls overlap: a plain area sample puts points inside the solid; ours does not."""
    mesh = library.processed("pybullet/classic/teddy").mesh
    plain, face = trimesh.sample.sample_surface(mesh, 2000, seed=0)
    plain_out = outside(mesh, plain + 1e-4 * mesh.face_normals[face])
    assert plain_out.mean() < 0.95  # the naive sample does have hidden points
    points, normals = sample_surface(mesh, 2000, seed=0)
    assert outside(mesh, points + 1e-5 * normals).all()


def test_same_seed_same_points_other_seed_other_points(library):
    a = library.point_cloud("procedural/mug/000", 256, seed=3)
    b = library.point_cloud("procedural/mug/000", 256, seed=3)
    c = library.point_cloud("procedural/mug/000", 256, seed=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.allclose(a[0], c[0])
    d = library.point_cloud("procedural/mug/000", 256, seed=3, fps=True)
    assert np.array_equal(d[0], library.point_cloud("procedural/mug/000", 256, seed=3, fps=True)[0])


@pytest.mark.parametrize("object_id", ["procedural/box/000", "pybullet/classic/bunny"])
def test_fps_covers_the_surface_better_than_random(library, object_id):
    n = 256
    rand, _ = library.point_cloud(object_id, n, seed=0)
    fps, fps_normals = library.point_cloud(object_id, n, seed=0, fps=True)
    assert fps.shape == (n, 3) and np.allclose(np.linalg.norm(fps_normals, axis=1), 1.0)

    def min_pair(p):
        d, _ = cKDTree(p).query(p, k=2)
        return d[:, 1].min()

    dense, _ = trimesh.sample.sample_surface(library.processed(object_id).mesh, 20000, seed=9)

    def cover_radius(p):
        return cKDTree(p).query(dense)[0].max()

    assert min_pair(fps) > 2 * min_pair(rand)
    assert cover_radius(fps) < cover_radius(rand)


def test_farthest_point_indices_on_a_line():
    points = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [4, 0, 0], [10, 0, 0]])
    assert farthest_point_indices(points, 3).tolist() == [0, 4, 3]
    assert farthest_point_indices(points, 9).tolist() == [0, 1, 2, 3, 4]


def test_nonpositive_count_is_an_error():
    with pytest.raises(AssetError, match="point cloud size must be positive, got 0"):
        sample_surface(trimesh.creation.box(), 0)


def test_the_bodies_of_a_mesh_are_found_once_and_forgotten_with_it(library):
    from ges_core.objects import pointcloud

    mesh = library.processed("pybullet/classic/teddy").mesh.copy()
    first = pointcloud._bodies(mesh)
    assert first is not None and first.labels.max() == 14
    assert pointcloud._bodies(mesh) is first  # cached: the second cloud does not split the mesh again
    twin = mesh.copy()
    assert pointcloud._bodies(twin) is not first  # another mesh object, its own entry
    assert np.array_equal(sample_surface(twin, 300, seed=2)[0], sample_surface(mesh, 300, seed=2)[0])
    key = id(mesh)
    del mesh, first
    gc.collect()  # a trimesh mesh holds reference cycles
    assert pointcloud._bodies(trimesh.creation.box()) is None  # one body: no hidden-surface test
    assert key not in pointcloud._CACHE  # that look-up dropped the entry of the freed mesh


def test_the_convex_inside_test_agrees_with_ray_parity_despite_a_zero_area_face():
    from ges_core.objects.pointcloud import _inside_test

    box = trimesh.creation.box((0.04, 0.03, 0.02))
    u, v, w = box.faces[0]
    m = len(box.vertices)  # a vertex in the middle of edge u-v splits face 0; the sliver (u, v, m) closes the seam
    vertices = np.vstack([box.vertices, (box.vertices[u] + box.vertices[v]) / 2])
    faces = np.vstack([[u, m, w], [m, v, w], box.faces[1:], [u, v, m]])
    body = trimesh.Trimesh(vertices, faces, process=False)
    assert body.is_watertight and body.is_winding_consistent and body.is_convex
    assert np.count_nonzero(np.abs(body.face_normals).sum(axis=1) == 0) == 1  # the sliver's normal is (0, 0, 0)
    points = np.random.default_rng(0).uniform(-0.025, 0.025, size=(2000, 3))
    planes = _inside_test(body)(points)
    assert planes.sum() > 100 and np.array_equal(planes, box.contains(points))
