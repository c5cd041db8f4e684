"""Mesh loading, repair and rejection: every error names the file and the reason."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.errors import AssetError
from ges_core.objects.sources import pybullet_data_dir, urdf_mesh
from ges_core.objects.validate import is_convex, load_mesh_file, repair_mesh


def write_obj(path, vertices, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def box_obj(path, extents=(0.05, 0.04, 0.03)):
    box = trimesh.creation.box(extents=extents)
    return write_obj(path, box.vertices, box.faces)


def test_nan_vertices_rejected(tmp_path):
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    vertices = box.vertices.astype(object)
    vertices[2] = ("nan", 0.0, 0.0)
    path = write_obj(tmp_path / "nan.obj", vertices, box.faces)
    with pytest.raises(AssetError, match=r"nan\.obj.*1 vertices are NaN or infinite"):
        repair_mesh(load_mesh_file(path), name=str(path))


def test_flat_mesh_rejected_as_zero_volume(tmp_path):
    quad = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], dtype=float)
    path = write_obj(tmp_path / "flat.obj", quad, [[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
    with pytest.raises(AssetError, match=r"flat\.obj: zero volume \(flat: 0 mm thick"):
        repair_mesh(load_mesh_file(path), name=str(path))


def test_all_degenerate_faces_rejected(tmp_path):
    path = write_obj(tmp_path / "line.obj", [[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], [[0, 1, 2]])
    with pytest.raises(AssetError, match=r"line\.obj: zero volume \(every face is degenerate"):
        repair_mesh(load_mesh_file(path), name=str(path))


def test_open_tube_is_not_repairable(tmp_path):
    tube = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=32)
    side = np.abs(tube.face_normals[:, 2]) < 0.5  # drop both caps: two 32-sided holes
    path = write_obj(tmp_path / "tube.obj", tube.vertices, tube.faces[side])
    with pytest.raises(AssetError, match=r"tube\.obj: not watertight after repair \(64 open edges"):
        repair_mesh(load_mesh_file(path), name=str(path))


def test_fin_sheet_is_rejected(tmp_path):
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    a, b = box.edges_unique[0]
    vertices = np.vstack([box.vertices, [[0.2, 0.2, 0.2]]])
    path = write_obj(tmp_path / "fin.obj", vertices, np.vstack([box.faces, [[a, b, len(box.vertices)]]]))
    with pytest.raises(AssetError, match=r"fin\.obj: zero volume in 1 of its separate bodies"):
        repair_mesh(load_mesh_file(path), name=str(path))


def test_tiny_fin_is_dropped_and_the_mesh_kept(tmp_path):
    """A scanner's sliver (as in 10 of the YCB scans): a face far below FIN_AREA hinged on a box edge."""
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    a, b = box.edges_unique[0]
    tip = box.vertices[[a, b]].mean(axis=0) + 1e-7  # 0.17 um off the edge: about 4e-9 m^2
    vertices = np.vstack([box.vertices, [tip]])
    path = write_obj(tmp_path / "sliver.obj", vertices, np.vstack([box.faces, [[a, b, len(box.vertices)]]]))
    mesh = repair_mesh(load_mesh_file(path), name=str(path))
    assert mesh.is_watertight and len(mesh.faces) == len(box.faces)
    assert mesh.volume == pytest.approx(0.05**3)


def test_bodies_sharing_an_edge_are_split_not_welded(tmp_path):
    """Two closed tetrahedra sharing one edge through the same vertex indices become two bodies."""
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    vertices = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05], [0.05, 0, -0.05], [0, -0.05, -0.05]])
    other = np.array([[0, 1, 4], [0, 4, 5], [1, 5, 4], [0, 5, 1]])
    path = write_obj(tmp_path / "bowtie.obj", vertices, np.vstack([tet, other]))
    mesh = repair_mesh(load_mesh_file(path), name=str(path))
    assert mesh.is_watertight and mesh.body_count == 2
    assert mesh.volume == pytest.approx(2 * 0.05**3 / 6)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(AssetError, match=r"nope\.obj: mesh file not found"):
        load_mesh_file(tmp_path / "nope.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(AssetError, match=r"empty\.obj: (file holds no triangles|cannot read mesh)"):
        load_mesh_file(empty)


def test_repair_fixes_duplicates_winding_and_a_small_hole(tmp_path):
    box = trimesh.creation.box(extents=(0.05, 0.04, 0.03))
    faces = box.faces.copy()
    faces[:3] = faces[:3, ::-1]  # three faces wound inward
    soup = box.vertices[faces].reshape(-1, 3)  # every face its own vertices (as OBJ exports with seams)
    soup_faces = np.arange(len(soup)).reshape(-1, 3)[1:]  # and one triangle missing
    path = write_obj(tmp_path / "messy.obj", soup, soup_faces)
    mesh = repair_mesh(load_mesh_file(path), name="messy")
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(0.05 * 0.04 * 0.03, rel=1e-9)


def test_scale_is_applied_per_axis(tmp_path):
    mesh = load_mesh_file(box_obj(tmp_path / "b.obj", (1.0, 1.0, 1.0)), scale=(0.1, 0.2, 0.3))
    assert np.allclose(mesh.extents, (0.1, 0.2, 0.3))


def test_parts_glued_along_an_edge_stay_separate():
    """random_urdfs/099 has two convex parts sharing an exact edge; a global vertex merge would make
    an edge of four faces. The per-body fallback keeps it watertight."""
    mesh_path, scale = urdf_mesh(pybullet_data_dir() / "random_urdfs" / "099" / "099.urdf")
    raw = load_mesh_file(mesh_path, scale=scale)
    welded = raw.copy()
    welded.merge_vertices()
    assert not welded.is_watertight
    mesh = repair_mesh(raw, name="099")
    assert mesh.is_watertight
    assert mesh.body_count == mesh_path.read_text().count("\no ") + mesh_path.read_text().startswith("o ")


def test_is_convex():
    assert is_convex(trimesh.creation.box(extents=(1, 2, 3)))
    assert not is_convex(trimesh.creation.torus(major_radius=1.0, minor_radius=0.2))
