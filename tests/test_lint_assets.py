"""The linter's checks for hands brought from elsewhere: tip frames, mimic tags, mesh formats, hull overlaps,
thumb opposition and the fingertip-force probe; each on a small broken gripper and on the Ability hand."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ges_core.cli import main
from ges_core.hand_files import FileHand
from ges_core.hand_prep.meshes import converted_mesh, resolve_mesh_path
from ges_core.lint import lint_hand
from ges_core.lint.checks_assets import check_tip_collision
from ges_core.lint.urdf_tree import UrdfTree

from conftest import EXAMPLE_HAND_PKG, REPO
from helpers_hands import PALM_BOX, write_l_palm_hand

SRC = EXAMPLE_HAND_PKG / "ges_example_hand"
URDF, YAML = (SRC / "gripper.urdf").read_text(), (SRC / "gripper.yaml").read_text()
MANI = Path(list(importlib.util.find_spec("mani_skill").submodule_search_locations)[0]) / "assets" / "robots"
ABILITY_GLB = MANI / "ability_hand" / "ability_hand_right_glb.urdf"
ABILITY_YAML = REPO / "tests" / "data" / "ability_raw" / "ability_right.yaml"
INDEX_TIP = "tip_link: index_distal, tip_offset: [0.031, 0.0, 0.0], keypoint_links: [index_distal]"
INDEX_J2 = '<joint name="index_j2" type="revolute">'
NO_SIMS = ("--skip", "self-collision", "--skip", "fk")


def write_hand(tmp_path: Path, urdf=(), yaml=()) -> Path:
    """The example gripper with (old, new) substitutions; returns the YAML path."""
    u, y = URDF, YAML
    for old, new in urdf:
        assert old in u, old
        u = u.replace(old, new, 1)
    for old, new in yaml:
        assert old in y, old
        y = y.replace(old, new, 1)
    (tmp_path / "hand.urdf").write_text(u)
    (tmp_path / "hand.yaml").write_text(y)
    return tmp_path / "hand.yaml"


def lint(capsys, path: Path, *extra: str) -> tuple[int, list[str]]:
    code = main(["hand", "lint", str(path), *extra])
    return code, [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("[")]


def test_tip_frame_without_collision_names_the_parent_and_offset(capsys, tmp_path):
    path = write_hand(tmp_path, yaml=[(INDEX_TIP, "tip_link: index_tip, keypoint_links: [index_distal, index_tip]")])
    code, lines = lint(capsys, path, *NO_SIMS)
    assert code == 1
    (line,) = [ln for ln in lines if ln.startswith("[tip-collision]")]
    assert "'index_tip' has no collision geometry" in line and "`ges sim check` reads 0 N" in line
    assert "use tip_link: index_distal with tip_offset: [0.031, 0.0, 0.0]" in line


def test_tip_fix_composes_rotated_fixed_joints():
    """The offered tip_offset and pad_normal are the tip frame's point and pad in the solid parent's frame."""
    urdf = URDF.replace(
        '<joint name="index_tip_fixed" type="fixed"><parent link="index_distal"/><child link="index_tip"/>'
        '<origin xyz="0.031 0 0" rpy="0 0 0"/>',
        '<joint name="index_tip_fixed" type="fixed"><parent link="index_distal"/><child link="index_tip"/>'
        '<origin xyz="0.031 0 0" rpy="0 0 1.5707963267948966"/>',
    )
    from dataclasses import replace

    from ges_core.hand import FingerSpec

    hand = FileHand(SRC / "gripper.yaml", SRC / "gripper.urdf")
    finger = FingerSpec(
        name="index", slot="index", joints=("index_j1", "index_j2"), tip_link="index_tip",
        tip_offset=(0.01, 0.0, 0.0), pad_normal=(1.0, 0.0, 0.0),
    )  # fmt: skip
    d = replace(hand.description, fingers=(finger,))

    class Hand:
        description, name = d, "g"

        def urdf_text(self):
            return urdf

    (problem,) = check_tip_collision(Hand(), UrdfTree.from_text(urdf), "g")
    # tip x axis is the distal link's y axis: the point 1 cm along it sits at (0.031, 0.01, 0)
    assert "tip_offset: [0.031, 0.01, 0.0], pad_normal: [0.0, 1.0, 0.0]" in problem.fix


MIMIC = '<mimic joint="index_j1" multiplier="0.5" offset="0.1"/>'


def test_mimic_tag_is_a_note_with_its_coupling_and_the_open_pose_must_obey_it(capsys, tmp_path):
    path = write_hand(tmp_path, urdf=[('velocity="3"/></joint>\n  <link name="index_tip"/>',
                                       f'velocity="3"/>{MIMIC}</joint>\n  <link name="index_tip"/>')])  # fmt: skip
    code, lines = lint(capsys, path, *NO_SIMS)
    assert "[mimic] note: <mimic> handled as the coupling index_j2 = 0.5 x index_j1 + 0.1 rad" in "\n".join(lines)
    assert code == 1  # the open pose (all 0) puts index_j2 at 0, the coupling at 0.1
    assert any(re.search(r"\[mimic\] open_pose gives follower 'index_j2' 0.0000 rad .* 0.1000 rad", ln) for ln in lines)
    path = write_hand(tmp_path, urdf=[('velocity="3"/></joint>\n  <link name="index_tip"/>',
                                       f'velocity="3"/>{MIMIC}</joint>\n  <link name="index_tip"/>')],
                      yaml=[("open_pose: 0.0", "open_pose: {default: 0.0, index_j2: 0.1}")])  # fmt: skip
    code, lines = lint(capsys, path, *NO_SIMS)
    assert code == 0 and [ln for ln in lines if "note" not in ln] == [], lines


def _glb_palm(tmp_path: Path) -> str:
    """A palm collision mesh stored as .glb (same box as the gripper's)."""
    box = trimesh.creation.box(extents=[0.08, 0.08, 0.02])
    box.export(tmp_path / "palm.glb")
    return '<collision><origin xyz="0.04 0 0" rpy="0 0 0"/><geometry><mesh filename="palm.glb"/></geometry></collision>'


def test_glb_mesh_is_named_as_a_format_then_prepared(capsys, tmp_path):
    path = write_hand(tmp_path, urdf=[(PALM_BOX, _glb_palm(tmp_path))])
    code, lines = lint(capsys, path, *NO_SIMS)
    (line,) = [ln for ln in lines if ln.startswith("[meshes]")]
    assert code == 1 and "mesh palm.glb of palm (collision) is glTF binary (.glb), which pybullet cannot load" in line
    assert f"ges hand prepare {path}" in line and "does not exist" not in line
    assert main(["hand", "prepare", str(path), "--no-progress"]) == 0
    assert "1 mesh file(s) converted to OBJ" in capsys.readouterr().out
    code, lines = lint(capsys, path, *NO_SIMS)
    assert code == 0 and any(ln.startswith("[meshes] note: mesh palm.glb") for ln in lines), lines


def test_missing_mesh_is_named_missing(capsys, tmp_path):
    missing = PALM_BOX.replace('<box size="0.08 0.08 0.02"/>', '<mesh filename="nowhere/palm.stl"/>')
    code, lines = lint(capsys, write_hand(tmp_path, urdf=[(PALM_BOX, missing)]), *NO_SIMS)
    assert code == 1 and any(
        "[meshes] mesh" in ln and "palm.stl of palm (collision) does not exist" in ln for ln in lines
    )


@pytest.mark.slow
def test_hull_overlap_is_caught_and_prepare_removes_it(capsys, tmp_path):
    path = write_l_palm_hand(tmp_path)
    code, lines = lint(capsys, path, *NO_SIMS)
    found = [ln for ln in lines if ln.startswith("[hull-overlap]")]
    assert code == 1 and found, lines
    (gap,) = [ln for ln in lines if ln.startswith("[hull-gap]")]  # the palm is the one mesh; boxes are hulls
    match = re.search(r"palm_l\.obj \(link\(s\) palm\): its surface lies ([0-9.]+) mm below its convex hull", gap)
    assert match and float(match.group(1)) > 3 and f"ges hand prepare {path}" in gap, gap
    pattern = r"links '(index|thumb)_distal' and 'palm' .*hulls overlap by ([0-9.]+) mm "
    pattern += r"where the meshes are ([0-9.]+) mm apart"
    match = re.search(pattern, found[0])
    assert match and float(match.group(2)) > 5 and 4 < float(match.group(3)) < 9, found
    assert f"ges hand prepare {path}" in found[0]
    assert main(["hand", "prepare", str(path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"palm_l\.obj\s+palm\s+[0-9.]+ mm\s+[2-9]", out), out  # decomposed into 2+ parts
    code, lines = lint(capsys, path, *NO_SIMS)
    assert not [ln for ln in lines if ln.startswith(("[hull-overlap]", "[hull-gap]"))], lines


def test_parallel_fingers_cannot_oppose(capsys, tmp_path):
    """Both gripper fingers curl the same way: pads facing +z never face each other."""
    pads = [("keypoint_links: [thumb_distal]", "keypoint_links: [thumb_distal], pad_normal: [0, 0, 1]"),
            ("keypoint_links: [index_distal]", "keypoint_links: [index_distal], pad_normal: [0, 0, 1]")]  # fmt: skip
    code, lines = lint(capsys, write_hand(tmp_path, yaml=pads), *NO_SIMS)
    assert code == 1
    assert any(
        re.search(r"\[opposition\] no configuration of 2048 sampled .* 45 deg .*index 180 deg", ln) for ln in lines
    )
    facing = [(pads[0][0], "keypoint_links: [thumb_distal], pad_normal: [0, 1, 0]"),
              (pads[1][0], "keypoint_links: [index_distal], pad_normal: [0, -1, 0]")]  # fmt: skip
    code, lines = lint(capsys, write_hand(tmp_path, yaml=facing), *NO_SIMS)
    assert code == 0, lines


def test_raw_ability_files_lint(monkeypatch, tmp_path):
    """mani-skill's raw Ability URDF (.glb visuals, mimic tags, tip frames): what a new user meets first.

    An empty cache of its own: the session's shared one holds the .glb files' OBJ copies once another test
    (test_hand_prep*) has converted them, and then the meshes problem is only a note (checked last here)."""
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    hand = FileHand(ABILITY_YAML, ABILITY_GLB, strict=False)
    problems = lint_hand(hand, skip=("hull-overlap",))
    checks = {p.check for p in problems if not p.note}
    assert {"tip-collision", "meshes", "inertia"} <= checks
    meshes = [p for p in problems if p.check == "meshes"]
    assert all("cannot load" in str(p) and "ges hand prepare" in str(p) for p in meshes), meshes
    assert sum(p.check == "mimic" and p.note for p in problems) == 4
    assert sum(p.check == "tip-collision" for p in problems) == 5
    assert not [p for p in problems if p.check in ("opposition", "wrist-frame")]
    for name in set(re.findall(r'filename="([^"]+\.glb)"', ABILITY_GLB.read_text())):
        converted_mesh(resolve_mesh_path(name, ABILITY_GLB.parent))  # what `ges hand prepare` does for them
    converted = [p for p in lint_hand(hand, skip=("hull-overlap",)) if p.check == "meshes"]
    assert len(converted) == len(meshes) and all(p.note and "its OBJ copy" in str(p) for p in converted)


@pytest.mark.sim
@pytest.mark.parametrize("sim", ["pybullet", "sapien"])
def test_tip_force_probe_flags_a_weak_hand(capsys, tmp_path, sim):
    """Drives 400x weaker press 400x less (PD: force ~ Kp x angle); the weak hand's tips are reported."""
    from ges_core.lint.checks_probe import probe_tip_forces
    from ges_core.registry import load_registry

    registry = load_registry(autoload=False)
    strong, asked = probe_tip_forces(FileHand(write_hand(tmp_path), tmp_path / "hand.urdf"), registry.build_sim, sim)
    weak_yaml = write_hand(tmp_path, yaml=[("pd_stiffness: {default: 20.0}", "pd_stiffness: {default: 0.05}")])
    weak, _ = probe_tip_forces(FileHand(weak_yaml, tmp_path / "hand.urdf"), registry.build_sim, sim)
    assert asked == 5.0 and np.all(strong > 0.5) and np.all(weak < strong / 20), (strong, weak)  # 3.9 and 0.9 N
    code, lines = lint(capsys, weak_yaml, "--sim", sim, "--probe", "--skip", "fk", "--skip", "self-collision")
    found = [ln for ln in lines if ln.startswith("[tip-force]")]
    assert code == 1 and len(found) == 2 and all(f"in {sim} under validation's squeeze (asks 5 N" in ln for ln in found)
    assert all(re.search(r"(pressed only [0-9.]+ N|did not touch)", ln) for ln in found)
    assert all("declare the actuators' armature" in ln for ln in found)  # the gripper declares none


@pytest.mark.sim
@pytest.mark.parametrize("sim", ["pybullet", "sapien"])
def test_tip_force_of_a_heavily_damped_hand_says_lower_the_damping(capsys, tmp_path, sim):
    """The same stiffness with ten times the damping presses far less on the probe cube (a blocked drive's force
    falls with Kd in both engines: 0.3 / 1.6 N at Kd/Kp 0.1 s, 5.3 / 2.9 N at 0.0025 s, SAPIEN / PyBullet); the
    lint tells the damped hand to lower pd_damping first and names its Kd/Kp, and the light one passes."""
    from ges_core.lint.checks_probe import probe_tip_forces
    from ges_core.registry import load_registry

    registry = load_registry(autoload=False)
    yamls = {}
    for kd in (2.0, 0.05):  # Kp 20: Kd/Kp 0.1 s and 0.0025 s
        folder = tmp_path / f"kd{kd}"
        folder.mkdir()
        yamls[kd] = write_hand(folder, yaml=[("pd_damping: {default: 0.5}", f"pd_damping: {{default: {kd}}}")])
    damped, _ = probe_tip_forces(FileHand(yamls[2.0], yamls[2.0].with_suffix(".urdf")), registry.build_sim, sim)
    light, _ = probe_tip_forces(FileHand(yamls[0.05], yamls[0.05].with_suffix(".urdf")), registry.build_sim, sim)
    assert np.all(light > 2.5) and np.all(damped < light / 1.5), (damped, light)
    code, lines = lint(capsys, yamls[2.0], "--sim", sim, "--probe", "--skip", "fk", "--skip", "self-collision")
    found = [ln for ln in lines if ln.startswith("[tip-force]")]
    assert code == 1 and len(found) == 2
    assert all("fix: lower pd_damping of its joints first: their Kd/Kp is 0.1 s" in ln for ln in found)
    code, lines = lint(capsys, yamls[0.05], "--sim", sim, "--probe", "--skip", "fk", "--skip", "self-collision")
    assert not [ln for ln in lines if ln.startswith("[tip-force]")]
