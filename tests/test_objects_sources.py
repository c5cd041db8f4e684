"""Object sources: pybullet_data listing and URDF scales, named classics, user folders."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh

from ges_core.errors import AssetError, ConfigError
from ges_core.objects.processing import process_entry
from ges_core.objects.sources import CLASSICS, list_procedural, list_pybullet, list_user, pybullet_data_dir, urdf_mesh


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))


def test_random_urdfs_listing_finds_about_a_thousand_with_their_urdf_scale():
    entries = list_pybullet(classics=False)
    assert 990 <= len(entries) <= 1010
    assert entries[42].object_id == "pybullet/random_urdfs/042"
    assert len({e.object_id for e in entries}) == len(entries)
    urdf_text = (pybullet_data_dir() / "random_urdfs" / "042" / "042.urdf").read_text()
    scale = tuple(float(v) for v in re.search(r'<mesh filename="042.obj" scale="([^"]+)"', urdf_text).group(1).split())
    assert entries[42].scale == scale and entries[42].path.name == "042.obj" and entries[42].path.is_file()


def test_random_urdf_loads_at_hand_size_as_its_convex_parts():
    entry = list_pybullet(classics=False)[42]
    obj = process_entry(entry)
    assert obj.kind == "convex_parts"
    n_parts = len(re.findall(r"^o ", entry.path.read_text(), flags=re.M))
    assert obj.mesh.body_count == n_parts
    assert 0.03 < max(obj.mesh.extents) < 0.20  # 0.015 x the file's ~6-8 units


@pytest.mark.parametrize("name", list(CLASSICS))
def test_every_classic_loads_watertight_and_hand_sized(name):
    entry = next(e for e in list_pybullet(random_urdfs=False) if e.object_id == f"pybullet/classic/{name}")
    obj = process_entry(entry)
    assert obj.mesh.is_watertight and obj.volume > 0
    assert min(obj.mesh.extents) >= 0.005 and max(obj.mesh.extents) <= 0.20, obj.mesh.extents


def test_urdf_without_mesh_is_reported(tmp_path):
    urdf = tmp_path / "box.urdf"
    urdf.write_text(
        '<robot name="b"><link name="l"><collision><geometry><box size="1 1 1"/></geometry></collision></link></robot>'
    )
    with pytest.raises(AssetError, match=r"box\.urdf: no <mesh filename=\.\.\.> in any collision or visual geometry"):
        urdf_mesh(urdf)
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot")
    with pytest.raises(AssetError, match=r"bad\.urdf: cannot read URDF"):
        urdf_mesh(bad)


def test_urdf_visual_mesh_and_scale(tmp_path):
    urdf = tmp_path / "v.urdf"
    urdf.write_text(
        '<robot name="v"><link name="l"><visual><geometry><mesh filename="m/x.obj" scale="1 2 3"/>'
        "</geometry></visual></link></robot>"
    )
    assert urdf_mesh(urdf) == (tmp_path / "m" / "x.obj", (1.0, 2.0, 3.0))


def test_user_folder_discovery(tmp_path):
    box = trimesh.creation.box(extents=(0.05, 0.06, 0.07))
    (tmp_path / "blocks").mkdir()
    (tmp_path / "balls").mkdir()
    box.export(tmp_path / "blocks" / "b1.obj")
    box.export(tmp_path / "blocks" / "b2.stl")
    trimesh.creation.icosphere(radius=40.0).export(tmp_path / "balls" / "red.ply")  # millimetres
    (tmp_path / "blocks" / "notes.txt").write_text("ignored")
    (tmp_path / "loose.obj").write_text("ignored: not in a category folder")
    entries = list_user(tmp_path)
    assert [e.object_id for e in entries] == ["user/balls/red", "user/blocks/b1", "user/blocks/b2"]
    assert [e.category for e in entries] == ["balls", "blocks", "blocks"]
    mm = list_user(tmp_path, scale=0.001)[0]
    assert np.allclose(process_entry(mm).mesh.extents, 0.08, atol=0.002)


def test_user_folder_errors(tmp_path):
    with pytest.raises(
        AssetError, match=r"user object folder .*missing does not exist; lay it out as <category>/<instance>\.obj"
    ):
        list_user(tmp_path / "missing")
    (tmp_path / "cat").mkdir()
    trimesh.creation.box().export(tmp_path / "cat" / "a.obj")
    trimesh.creation.box().export(tmp_path / "cat" / "a.stl")
    trimesh.creation.box().export(tmp_path / "cat" / "b.obj")
    dup, other = list_user(tmp_path)  # two files with one id: that id is unusable, the folder is not
    assert (dup.object_id, other.object_id, other.problem) == ("user/cat/a", "user/cat/b", None)
    assert dup.problem.endswith("both give this object id; rename or remove all but one of them")
    with pytest.raises(AssetError, match=r"^user/cat/a: a\.obj and a\.stl in .* both give this object id"):
        process_entry(dup)


def test_unknown_procedural_category():
    with pytest.raises(ConfigError, match=r"unknown procedural categories \['spoon'\]; known: box, cube"):
        list_procedural(count=1, seed=0, categories=("spoon",))


def test_broken_pybullet_file_is_rejected_with_its_name():
    """random_urdfs/168 ships NaN vertices: the library rejects it, naming the file."""
    entry = list_pybullet(classics=False)[168]
    with pytest.raises(AssetError, match=r"random_urdfs/168 \(.*168\.obj\): 35 vertices are NaN or infinite"):
        process_entry(entry)
