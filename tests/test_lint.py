"""``ges hand lint``: the built-in hands pass, and every check catches a hand broken on purpose.

The broken hands are copies of the example gripper (tests/data/ges_example_hand) with one
defect each, written to a temp folder and linted through the real command.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from ges_core.cli import main
from ges_core.hand_files import FileHand
from ges_core.lint import lint_hand
from ges_core.lint.checks_physics import check_fk_matches_sims
from ges_core.registry import load_registry

from conftest import EXAMPLE_HAND_PKG

SRC = EXAMPLE_HAND_PKG / "ges_example_hand"
URDF, YAML = (SRC / "gripper.urdf").read_text(), (SRC / "gripper.yaml").read_text()


def broken_hand(tmp_path: Path, *, urdf: tuple[str, str] | None = None, yaml: tuple[str, str] | None = None) -> Path:
    """Write the gripper with one (old, new) substitution in its URDF or YAML; return the YAML path."""
    u, y = URDF, YAML
    if urdf:
        assert urdf[0] in u, urdf[0]
        u = u.replace(urdf[0], urdf[1], 1)
    if yaml:
        assert yaml[0] in y, yaml[0]
        y = y.replace(yaml[0], yaml[1], 1)
    (tmp_path / "hand.urdf").write_text(u)
    (tmp_path / "hand.yaml").write_text(y)
    return tmp_path / "hand.yaml"


def lint_lines(capsys, path: Path, *extra: str) -> tuple[int, list[str]]:
    code = main(["hand", "lint", str(path), *extra])
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("[")]
    return code, lines


def test_example_gripper_is_clean(capsys, tmp_path):
    """Clean but for one note: its index finger serves the middle and little slots, so Stage 1 (which tells the
    palm's left from its right by those two fingertips) refuses it; the lint says so before any run."""
    code, lines = lint_lines(capsys, broken_hand(tmp_path))
    assert code == 0 and len(lines) == 1, lines
    assert lines[0].startswith("[slots] note: hand 'example_gripper': one finger ('index') serves both the middle")


INDEX_J2_LIMIT = '<limit lower="0" upper="1.2" effort="10" velocity="3"/></joint>\n  <link name="index_tip"/>'
DISTAL_COLLISION = (
    '<collision><origin xyz="0.015 0 0" rpy="0 0 0"/><geometry><box size="0.03 0.016 0.016"/></geometry></collision>'
)


@pytest.mark.parametrize(
    ("defect", "expected"),
    [
        (
            {"urdf": (INDEX_J2_LIMIT, '</joint>\n  <link name="index_tip"/>')},
            r"\[joint-limits\] joint 'index_j2' has no limit",
        ),
        (
            {"yaml": ("open_pose: 0.0", "open_pose: {default: 0.0, index_j1: 2.0}")},
            r"\[joint-limits\] open pose of 'index_j1'",
        ),
        ({"yaml": (", little: index}", "}")}, r"\[slots\] no finger serves slot 'little'"),
        (
            {"yaml": ("tip_link: index_distal", "tip_link: index_proximal")},
            r"\[tip-links\] .*'index_proximal' is not distal",
        ),
        (
            {"yaml": ("keypoint_links: [index_distal", "keypoint_links: [thumb_distal")},
            r"\[tip-links\] .*keypoint 'thumb_distal'",
        ),
        (
            {"yaml": ("tip_link: thumb_distal", "tip_link: thumb_nail")},
            r"\[tip-links\] .*'thumb_nail' is not in the URDF",
        ),
        (
            {
                "urdf": (
                    f'{DISTAL_COLLISION}\n  </link>\n  <joint name="index_j1"',
                    '\n  </link>\n  <joint name="index_j1"',
                )
            },
            r"\[collision\] finger 'index': link 'index_distal' has no collision geometry",
        ),
        ({"urdf": ('<mass value="0.02"/>', '<mass value="0"/>')}, r"\[inertia\] link 'index_distal' has mass 0 kg"),
        (
            {"urdf": ('<mass value="0.02"/><inertia ixx="8.533e-07"', '<mass value="0.02"/><inertia ixx="1"')},
            r"\[inertia\] link 'index_distal' has an invalid inertia tensor",
        ),
        ({"yaml": ("palm_normal: [0, 0, 1]", "palm_normal: [0, 0, -1]")}, r"\[wrist-frame\] palm_normal is 180 deg"),
        (
            {"yaml": ("finger_direction: [1, 0, 0]", "finger_direction: [0, 1, 0]")},
            r"\[wrist-frame\] finger_direction is [0-9]+ deg",
        ),
    ],
)
def test_each_static_check_catches_its_defect(capsys, tmp_path, defect, expected):
    code, lines = lint_lines(capsys, broken_hand(tmp_path, **defect), "--skip", "self-collision", "--skip", "fk")
    assert code == 1
    assert any(re.search(expected, ln) for ln in lines), lines
    assert all(" -- fix: " in ln for ln in lines)


@pytest.mark.sim
@pytest.mark.parametrize("sim", ["sapien", "pybullet"])
def test_self_collision_at_open_pose_is_caught(capsys, tmp_path, sim):
    """Thumb mounted where the index finger is: the two fingers overlap completely."""
    path = broken_hand(tmp_path, urdf=('origin xyz="0.082 -0.03 0.01"', 'origin xyz="0.082 0.025 0.01"'))
    code, lines = lint_lines(capsys, path, "--sim", sim, "--skip", "fk")
    assert code == 1
    assert any(
        re.search(rf"\[self-collision\] open pose: links .*(thumb|index).* overlap .* in {sim}", ln) for ln in lines
    )


@pytest.mark.sim
@pytest.mark.parametrize("sim", ["sapien", "pybullet"])
def test_a_pair_listed_in_self_collision_exclude_is_not_collided(capsys, tmp_path, sim):
    """The overlapping thumb and index above, one of their two pairs listed in ``self_collision_exclude``: the engine
    no longer collides that pair (the check reads the engine's own contact pairs) and still collides the other."""
    moved = ('origin xyz="0.082 -0.03 0.01"', 'origin xyz="0.082 0.025 0.01"')
    path = broken_hand(tmp_path, urdf=moved)
    assert "self_collision_exclude" not in path.read_text()
    path.write_text(path.read_text() + "\nself_collision_exclude: [[thumb_distal, index_distal]]\n")
    code, lines = lint_lines(capsys, path, "--sim", sim, "--skip", "fk")
    found = [ln for ln in lines if ln.startswith("[self-collision]")]
    assert code == 1 and len(found) == 1
    assert re.search(r"'(thumb|index)_proximal' and '(thumb|index)_proximal'", found[0])


def test_self_collision_exclude_names_only_links_with_collision_geometry(tmp_path):
    """Unknown links, a link paired with itself and a link without collision geometry are refused, naming the links
    that can be listed; a good pair is stored with its names sorted."""
    from ges_core.errors import AssetError
    from ges_core.hand_files import FileHand

    path = broken_hand(tmp_path)
    text = path.read_text()
    for pair, message in (
        ("[thumb_distal, nope]", r"\[thumb_distal, nope\] names unknown link\(s\) \['nope'\]"),
        ("[thumb_distal, thumb_distal]", r"pairs a link with itself"),
        ("[thumb_distal, index_tip]", r"\['index_tip'\] has no collision geometry"),
    ):
        path.write_text(text + f"\nself_collision_exclude: [{pair}]\n")
        with pytest.raises(AssetError, match=message + r".*links with collision geometry: \[.*'palm'"):
            _ = FileHand(path, tmp_path / "hand.urdf").description
    path.write_text(text + "\nself_collision_exclude: [[thumb_distal, index_distal]]\n")
    hand = FileHand(path, tmp_path / "hand.urdf")
    assert hand.description.self_collision_exclude == (("index_distal", "thumb_distal"),)
    assert frozenset(("index_distal", "thumb_distal")) in hand.excluded_link_pairs()


class _ShiftedSim:
    """Test double: a real backend whose link poses are shifted 5 mm, as a wrongly parsed URDF would be."""

    def __init__(self, real):
        self._real = real

    def __getattr__(self, name):
        return getattr(self._real, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._real.close()

    def link_poses(self, links):
        poses = self._real.link_poses(links)
        poses[..., 0] += 0.005
        return poses


@pytest.mark.sim
def test_fk_mismatch_is_caught():
    registry = load_registry(autoload=False)
    hand = FileHand(SRC / "gripper.yaml", SRC / "gripper.urdf")
    problems = check_fk_matches_sims(hand, "pybullet", lambda n, c: _ShiftedSim(registry.build_sim(n, c)))
    assert problems and all(p.check == "fk" and "5.00 mm apart" in p.what for p in problems)
    assert check_fk_matches_sims(hand, "pybullet", registry.build_sim) == []


@pytest.mark.sim
@pytest.mark.parametrize("name", ["allegro", "shadow"])
def test_builtin_hands_pass_every_check_in_every_sim(name):
    registry = load_registry(autoload=False)
    problems = lint_hand(registry.build_hand(name), sims=registry.names("sim"), make_sim=registry.build_sim)
    assert [str(p) for p in problems] == []


def test_lint_of_missing_files_is_one_line(capsys, tmp_path):
    code = main(["hand", "lint", str(tmp_path / "nope.yaml")])
    assert code == 1 and "hand file" in capsys.readouterr().err


def test_closed_pose_moves_fingers_toward_palm_normal():
    """The linter's palm-normal check relies on closed_pose curling the fingers; check it on the gripper."""
    hand = FileHand(SRC / "gripper.yaml", SRC / "gripper.urdf")
    closed = hand.description.closed_pose()
    assert np.all(closed >= np.asarray(hand.description.open_pose))
    assert np.any(closed > 0.1)
