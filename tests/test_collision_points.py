"""Collision-geometry points of a URDF, checked against trimesh's own shapes and the built-in hands."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.collision_points import collision_parts, collision_points
from ges_core.errors import AssetError
from ges_core.registry import load_registry

URDF = """<robot name="shapes">
  <link name="box"><collision><origin xyz="0.1 0 0" rpy="0 0 1.5707963"/>
    <geometry><box size="0.2 0.1 0.06"/></geometry></collision></link>
  <link name="caps"><collision><geometry><capsule radius="0.01" length="0.04"/></geometry></collision></link>
  <link name="mesh"><collision><geometry><mesh filename="{mesh}" scale="2 2 2"/></geometry></collision></link>
  <link name="empty"/>
</robot>"""


def test_points_lie_on_each_shape(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    path = tmp_path / "ball.obj"
    mesh.export(path)
    pts = collision_points(URDF.format(mesh=path), max_mesh_points=10)
    assert set(pts) == {"box", "caps", "mesh"}  # no collision, no points
    # the box turned 90 degrees about z and moved 0.1 m along x: corners at x = 0.1 +- 0.05, y = +-0.1
    np.testing.assert_allclose(np.sort(np.unique(pts["box"][:, 0].round(6))), [0.05, 0.15], atol=1e-6)
    np.testing.assert_allclose(np.sort(np.unique(pts["box"][:, 1].round(6))), [-0.1, 0.1], atol=1e-6)
    assert len(pts["box"]) == 8
    assert np.isclose(pts["caps"][:, 2].max(), 0.03) and np.isclose(pts["caps"][:, 2].min(), -0.03)
    radii = np.linalg.norm(pts["mesh"], axis=1)  # hull vertices of a 3 cm sphere scaled by 2
    assert len(pts["mesh"]) == 10 and np.allclose(radii, 0.06, atol=1e-6)


def test_missing_mesh_and_unknown_shape_are_named(tmp_path):
    with pytest.raises(AssetError, match=r"mesh '.*nowhere.obj' not found"):
        collision_points(URDF.format(mesh=tmp_path / "nowhere.obj"))
    with pytest.raises(AssetError, match=r"unknown URDF geometry <cone>"):
        collision_points(
            '<robot name="r"><link name="a"><collision><geometry><cone/></geometry></collision></link></robot>'
        )


@pytest.mark.parametrize("name", ["allegro", "shadow"])
def test_every_finger_link_of_the_built_in_hands_has_points(name):
    hand = load_registry().build_hand(name)
    pts = collision_points(hand.urdf_text())
    for f in hand.description.fingers:
        assert f.tip_link in pts, f"{name}: fingertip link {f.tip_link} has no collision points"
        # the fingertip point (tip_offset) lies on the tip geometry's extent: within its points' bounding box
        lo, hi = pts[f.tip_link].min(axis=0), pts[f.tip_link].max(axis=0)
        assert np.all(np.asarray(f.tip_offset) >= lo - 2e-3) and np.all(np.asarray(f.tip_offset) <= hi + 2e-3)


def test_a_link_of_many_parts_keeps_its_hull_and_a_spread_of_the_rest(tmp_path):
    """A link made of 30 small cube meshes (as `ges hand prepare` writes a decomposed mesh) keeps at most
    max_link_points of the 30 x 8 corners: every kept point is one of them; for twenty random directions the lowest
    kept point is within one part's size (1 cm) of the lowest corner (what meets a table first, checked against all
    corners); every cube keeps a point within 1 cm of its centre, the inner ones too; and the choice repeats."""
    rng = np.random.default_rng(3)
    parts, centres = [], rng.uniform(-0.05, 0.05, size=(30, 3))
    for i, c in enumerate(centres):
        path = tmp_path / f"part{i}.obj"
        trimesh.creation.box(extents=(0.01, 0.01, 0.01)).apply_translation(c).export(path)
        parts.append(f'<collision><geometry><mesh filename="{path}"/></geometry></collision>')
    urdf = f'<robot name="r"><link name="palm">{"".join(parts)}</link></robot>'
    every = collision_points(urdf, max_link_points=10_000)["palm"]
    kept = collision_points(urdf, max_link_points=60)["palm"]
    assert len(every) == 240 and len(kept) == 60
    assert all(np.isclose(every, p, atol=1e-9).all(axis=1).any() for p in kept)
    for direction in rng.normal(size=(20, 3)):
        direction /= np.linalg.norm(direction)
        assert (kept @ direction).min() - (every @ direction).min() < 0.01  # a part's size
    gaps = np.linalg.norm(centres[:, None] - kept[None], axis=-1).min(axis=1)
    assert gaps.max() < 0.01, gaps.max()
    np.testing.assert_array_equal(kept, collision_points(urdf, max_link_points=60)["palm"])


def test_collision_parts_are_the_links_points_one_element_each(tmp_path):
    """collision_parts gives each <collision> element on its own, in file order: a link of two parts gives two
    entries whose joined points are the link's collision_points (under the cap), each part's corners its own."""
    paths = []
    for i, centre in enumerate([(0.0, 0.0, 0.0), (0.05, 0.0, 0.0)]):
        paths.append(tmp_path / f"part{i}.obj")
        trimesh.creation.box(extents=(0.01, 0.02, 0.03)).apply_translation(centre).export(paths[-1])
    meshes = "".join(f'<collision><geometry><mesh filename="{path}"/></geometry></collision>' for path in paths)
    urdf = URDF.format(mesh=paths[0]).replace('<link name="empty"/>', f'<link name="two">{meshes}</link>')
    parts = collision_parts(urdf)
    assert [link for link, _ in parts] == ["box", "caps", "mesh", "two", "two"]
    (_, first), (_, second) = parts[-2:]
    np.testing.assert_allclose(first.mean(axis=0), [0.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(second.mean(axis=0), [0.05, 0.0, 0.0], atol=1e-9)
    assert len(first) == len(second) == 8
    np.testing.assert_array_equal(np.concatenate([first, second]), collision_points(urdf)["two"])
