"""ges_core.hand_prep: mimic tags as couplings, mesh conversion, the engine URDF, hull measurements."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from ges_core.errors import AssetError
from ges_core.hand import JointCoupling
from ges_core.hand_files import FileHand
from ges_core.hand_prep.engine_files import engine_file_memo, note_parts_written
from ges_core.hand_prep.engine_urdf import engine_urdf
from ges_core.hand_prep.geometry import hull_penetration, link_shapes, mesh_gap
from ges_core.hand_prep.meshes import converted_mesh, converted_mesh_if_cached, resolve_mesh_path
from ges_core.hand_prep.mimic import mimic_couplings, strip_mimic
from ges_core.kinematics import HandKinematics
from ges_core.paths import CACHE_ENV, cached_text_file
from ges_core.urdf import parse_urdf

from conftest import REPO

MANI = Path(list(importlib.util.find_spec("mani_skill").submodule_search_locations)[0]) / "assets" / "robots"
ABILITY = MANI / "ability_hand" / "ability_hand_right.urdf"
ABILITY_GLB = MANI / "ability_hand" / "ability_hand_right_glb.urdf"
INSPIRE = MANI / "inspire_hand" / "RH56DFX-2LR" / "urdf" / "inspire_hand_right.urdf"
ABILITY_YAML = REPO / "tests" / "data" / "ability_raw" / "ability_right.yaml"

TWO_JOINTS = """<robot name="t">
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0.1 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>{m2}</joint>
  <joint name="j3" type="revolute"><parent link="c"/><child link="d"/><origin xyz="0.1 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>{m3}</joint>
</robot>"""


def test_ability_mimic_tags_become_couplings_with_offset():
    couplings = mimic_couplings(ABILITY.read_text())
    assert [c.follower for c in couplings] == ["index_q2", "middle_q2", "ring_q2", "pinky_q2"]
    assert all(c.leader == c.follower.replace("q2", "q1") for c in couplings)
    assert all(c.ratio == pytest.approx(1.05851325) and c.offset == pytest.approx(0.72349796) for c in couplings)


def test_inspire_mimic_chain_resolves_to_the_original_tag():
    """The Inspire file rewrote its thumb IP tag to mimic the MCP joint (0.5 x MCP) and kept the original
    (0.6667 x CMC pitch - 0.0407) in a comment: resolving the chain must give the original back."""
    couplings = {c.follower: c for c in mimic_couplings(INSPIRE.read_text())}
    ip = couplings["right_hand_thumb_IP_joint"]
    assert ip.leader == "right_hand_thumb_CMC_pitch_joint"
    assert ip.ratio == pytest.approx(0.6666666666666667) and ip.offset == pytest.approx(-0.040724349213201026)
    assert all(c.leader not in couplings for c in couplings.values())


@pytest.mark.parametrize(
    ("m2", "m3", "message"),
    [
        ('<mimic joint="j3"/>', '<mimic joint="j2"/>', "cycle"),
        ('<mimic joint="nope"/>', "", "not movable joints"),
        ('<mimic joint="j1" multiplier="x"/>', "", "non-numeric"),
    ],
)
def test_bad_mimic_tags(m2, m3, message):
    with pytest.raises(AssetError, match=message):
        mimic_couplings(TWO_JOINTS.format(m2=m2, m3=m3))


def test_apply_couplings_uses_ratio_and_offset():
    from dataclasses import replace

    hand = FileHand(ABILITY_YAML, ABILITY)
    d = replace(
        hand.description, couplings=(JointCoupling(follower="index_q2", leader="index_q1", ratio=2.0, offset=0.3),)
    )
    q = np.zeros((3, d.num_joints))
    q[:, d.joint_index(["index_q1"])[0]] = [0.0, 0.5, 1.0]
    out = d.apply_couplings(q)[:, d.joint_index(["index_q2"])[0]]
    assert np.allclose(out, [0.3, 1.3, 2.3])


def test_file_hand_adds_mimic_couplings_and_kinematics_follows_the_formula():
    """The mimic tags' couplings set each follower to multiplier * leader + offset (within its limits), and FK
    places the followers' links where those values put them (not where the drawn, uncoupled values would)."""
    hand = FileHand(ABILITY_YAML, ABILITY)
    d = hand.description
    assert {c.follower for c in d.couplings} == {"index_q2", "middle_q2", "ring_q2", "pinky_q2"}
    kin = HandKinematics.from_hand(hand)
    q = np.random.default_rng(1).uniform(*d.limits_array.T, size=(16, d.num_joints))
    coupled = d.apply_couplings(q)
    manual = q.copy()
    for c in d.couplings:
        i, j = d.joint_index([c.follower, c.leader])
        manual[:, i] = np.clip(c.ratio * q[:, j] + c.offset, *d.limits_array[i])
    assert np.allclose(coupled, manual)
    links = ["index_L2", "index_tip", "pinky_tip"]
    drawn, followed = kin.link_poses(torch.as_tensor(q), links), kin.link_poses(torch.as_tensor(coupled), links)
    assert not torch.allclose(drawn, followed, atol=1e-3)


def test_strip_mimic_removes_tags_and_keeps_text_without_them():
    text = ABILITY.read_text()
    assert "<mimic" not in strip_mimic(text)
    allegro = (MANI / "allegro" / "allegro_hand_right.urdf").read_text()
    assert strip_mimic(allegro) is allegro


def test_builtin_hand_urdfs_reach_the_engines_unchanged():
    """engine_urdf returns the very same text for the built-in hands (what their engines load is unchanged)."""
    from ges_core.registry import load_registry

    registry = load_registry(autoload=False)
    for name in ("allegro", "shadow"):
        hand = registry.build_hand(name)
        text = hand.urdf_text()
        assert engine_urdf(text, hand.urdf_path().parent) is text


def test_glb_meshes_are_converted_and_the_urdf_points_at_the_objs():
    out = engine_urdf(ABILITY_GLB.read_text(), ABILITY_GLB.parent)
    root = parse_urdf(out)
    names = [m.get("filename") for m in root.iter("mesh")]
    assert names and all(Path(n).is_absolute() and Path(n).suffix in (".obj", ".stl") for n in names)
    assert "<mimic" not in out
    glb = ABILITY_GLB.parent / "meshes" / "visual" / "idx-F1.glb"
    obj = converted_mesh_if_cached(glb)
    assert obj is not None and obj.name.startswith("idx-F1_")
    src, conv = trimesh.load(str(glb), force="mesh"), trimesh.load(str(obj), force="mesh")
    assert np.allclose(src.bounds, conv.bounds, atol=1e-6) and len(conv.faces) == len(src.faces)


def test_converting_a_missing_or_unreadable_mesh_names_the_file(tmp_path):
    with pytest.raises(AssetError, match="does not exist"):
        converted_mesh(tmp_path / "gone.glb")
    bad = tmp_path / "bad.ply"
    bad.write_text("this is no mesh")
    with pytest.raises(AssetError, match="bad.ply"):
        converted_mesh(bad)


def test_a_missing_collision_mesh_names_the_link_and_the_fix(tmp_path):
    urdf = '<robot name="r"><link name="palm"><collision><geometry><mesh filename="gone.stl"/></geometry></collision>'
    with pytest.raises(AssetError, match=r"link 'palm': collision mesh .*gone.stl does not exist; fix the URDF's"):
        link_shapes(urdf + "</link></robot>", tmp_path)


def test_a_capsule_is_read_with_its_length_as_the_cylinder_part(tmp_path):
    """<capsule radius length>: length between the cap centres, axis z (as PyBullet and SAPIEN read it); left out
    with ``capsules=False`` (the inertia bound's reading)."""
    urdf = (
        '<robot name="r"><link name="f"><collision><origin xyz="0 0 0.1"/><geometry><capsule radius="0.01" '
        'length="0.04"/></geometry></collision></link></robot>'
    )
    (shape,) = link_shapes(urdf, tmp_path)["f"]
    assert shape.primitive
    np.testing.assert_allclose(shape.mesh.bounds, [[-0.01, -0.01, 0.07], [0.01, 0.01, 0.13]], atol=1e-3)
    assert link_shapes(urdf, tmp_path, capsules=False) == {}


def test_package_paths_resolve_in_a_robot_description_layout(tmp_path):
    pkg = tmp_path / "my_hand_description"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "meshes" / "palm.stl").write_text("solid x\nendsolid x\n")
    found = resolve_mesh_path("package://my_hand_description/meshes/palm.stl", pkg / "urdf")
    assert found == pkg / "meshes" / "palm.stl"
    assert resolve_mesh_path("file:///abs/m.obj", pkg) == Path("/abs/m.obj")
    assert resolve_mesh_path("m.obj", pkg / "urdf") == (pkg / "urdf" / "m.obj")


def _box(extents, centre):
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(centre)
    return box


def test_hull_penetration_and_mesh_gap_of_boxes():
    """Two unit-free boxes: 4 mm overlap along x, then 3 mm apart (exact answers of the geometry)."""
    a = _box([0.02, 0.02, 0.02], [0, 0, 0])
    b = _box([0.02, 0.02, 0.02], [0.016, 0.005, 0])
    assert hull_penetration(np.asarray(a.vertices), np.asarray(b.vertices)) == pytest.approx(0.004, abs=1e-9)
    assert mesh_gap(a, b) == pytest.approx(-0.004, abs=2e-4)
    c = _box([0.02, 0.02, 0.02], [0.023, 0, 0])
    assert hull_penetration(np.asarray(a.vertices), np.asarray(c.vertices)) == 0.0
    assert mesh_gap(a, c) == pytest.approx(0.003, abs=1e-6)


def test_an_engine_file_is_made_once_per_process_and_again_when_it_may_be_stale(tmp_path, monkeypatch):
    """The same arguments give the file made the first time; other arguments, a removed file, a decomposition
    written since (its parts belong in the file) or another cache folder make it again."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "a"))
    made = []

    @engine_file_memo
    def make(text: str, *, floating: bool) -> Path:
        made.append((text, floating))
        return cached_text_file(f"{text} {floating}", "test", stem="hand")

    first = make("<robot/>", floating=True)
    assert make("<robot/>", floating=True) == first and len(made) == 1
    assert make("<robot/>", floating=False) != first and len(made) == 2
    first.unlink()
    assert make("<robot/>", floating=True) == first and first.is_file() and len(made) == 3
    note_parts_written()
    assert make("<robot/>", floating=True) == first and len(made) == 4
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "b"))
    moved = make("<robot/>", floating=True)
    assert moved.is_relative_to(tmp_path / "b") and len(made) == 5
