"""Hand descriptions: YAML parsing and per-joint expansion (hand_yaml.py), and HandDescription helpers (hand.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import AssetError
from ges_core.hand_yaml import description_from_yaml, expand_per_joint, urdf_joint_limits

# Two fingers of two joints (limits differ per joint), a fixed tip per finger, a thumb-like finger.
URDF = """<?xml version="1.0"?>
<robot name="mini">
  <link name="palm"/>
  <link name="f1"/><link name="f2"/><link name="f_tip"/>
  <link name="t1"/><link name="t2"/><link name="t_tip"/>
  <joint name="ff_j1" type="revolute"><parent link="palm"/><child link="f1"/><axis xyz="0 1 0"/>
    <limit lower="-0.2" upper="1.5" effort="1" velocity="1"/></joint>
  <joint name="ff_j2" type="revolute"><parent link="f1"/><child link="f2"/><axis xyz="0 1 0"/>
    <origin xyz="0 0 0.05"/><limit lower="0" upper="1.0" effort="1" velocity="1"/></joint>
  <joint name="ff_tip" type="fixed"><parent link="f2"/><child link="f_tip"/><origin xyz="0 0 0.03"/></joint>
  <joint name="th_j1" type="revolute"><parent link="palm"/><child link="t1"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="th_j2" type="prismatic"><parent link="t1"/><child link="t2"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="0.02" effort="1" velocity="1"/></joint>
  <joint name="th_tip" type="fixed"><parent link="t2"/><child link="t_tip"/></joint>
</robot>
"""
JOINTS = ["ff_j1", "ff_j2", "th_j1", "th_j2"]

YAML = """
name: mini
fingers:
  - {name: ff, slot: index, joints: [ff_j1, ff_j2], tip_link: f_tip, tip_offset: [0.01, 0, 0]}
  - {name: th, slot: thumb, joints: [th_j1, th_j2], tip_link: t_tip}
slot_fill: {middle: ff, ring: ff, little: ff}
wrist: {link: palm, palm_normal: [1, 0, 0], finger_direction: [0, 0, 1]}
middle_finger_length: 0.08
scale: 0.8
open_pose: {"ff_.*": 0.1, "th_j1": -0.5, default: 0.0}
pd_stiffness: {default: 5.0, "th_.*": 2.0}
pd_damping: 0.1
couplings: [{follower: ff_j2, leader: ff_j1, ratio: 0.5}]
"""


def describe(yaml_text: str = YAML, urdf_text: str = URDF, **overrides):
    return description_from_yaml(yaml_text, urdf_text, **overrides)


def test_a_settings_override_merges_into_the_yamls_settings_key_by_key():
    """``ges --set settings.hand.NAME.settings.validate.KEY=V`` reaches the YAML as a ``settings`` override: it changes
    that key and keeps the hand's others (before, it replaced the YAML's whole ``settings:``, and a hand's squeeze force
    went back to the run default); every other override still replaces its key."""
    own = YAML + "settings: {validate: {squeeze_force: 7.0, min_tips: 3}, thumb_keep: 1}\n"
    merged = describe(own, settings={"validate": {"max_squeeze": 1.0}}, scale=1.0).settings
    assert merged == {"validate": {"squeeze_force": 7.0, "min_tips": 3, "max_squeeze": 1.0}, "thumb_keep": 1}
    assert describe(own, settings={"validate": {"squeeze_force": 5.0}}).settings["validate"]["squeeze_force"] == 5.0
    assert describe(own).settings == {"validate": {"squeeze_force": 7.0, "min_tips": 3}, "thumb_keep": 1}
    assert describe(own, scale=1.0).scale == 1.0 and describe(own).scale == 0.8  # a plain key: replaced


# -- per-joint values ---------------------------------------------------------------------
def test_regex_keys_expand_per_joint():
    assert expand_per_joint({"ff_.*": 1.0, "default": 0.5}, JOINTS, "x") == (1.0, 1.0, 0.5, 0.5)
    assert expand_per_joint({r"th_j\d": 2.0, "ff_j[12]": 3.0}, JOINTS, "x") == (3.0, 3.0, 2.0, 2.0)  # no default


def test_regex_keys_are_full_matches_and_the_first_match_wins():
    assert expand_per_joint({"ff_j1": 1.0, "ff_.*": 2.0, "default": 0.0}, JOINTS, "x") == (1.0, 2.0, 0.0, 0.0)
    with pytest.raises(AssetError, match=r"x: pattern 'ff' matches no joint \(joints: ff_j1, ff_j2, th_j1, th_j2\)"):
        expand_per_joint({"ff": 1.0, "default": 0.0}, JOINTS, "x")


def test_scalar_and_list_values():
    assert expand_per_joint(2, JOINTS, "x") == (2.0,) * 4
    assert expand_per_joint([1, 2, 3, 4], JOINTS, "x") == (1.0, 2.0, 3.0, 4.0)
    with pytest.raises(AssetError, match="mini.gains: list has 3 values for 4 joints"):
        expand_per_joint([1, 2, 3], JOINTS, "mini.gains")


def test_missing_values_without_default():
    with pytest.raises(AssetError, match="pd: no value for th_j1, th_j2; add them or a 'default'"):
        expand_per_joint({"ff_.*": 1.0}, JOINTS, "pd")


def test_description_expands_every_per_joint_table():
    d = describe()
    assert d.joint_names == tuple(JOINTS)  # URDF file order when joint_names is not given
    assert d.open_pose == (0.1, 0.1, -0.5, 0.0)
    assert d.pd_stiffness == (5.0, 5.0, 2.0, 2.0)
    assert d.pd_damping == (0.1,) * 4


def test_effort_limits_are_optional_and_expanded_per_joint():
    d = describe()
    assert d.effort_limits == () and d.effort_limits_array is None  # the file gives none
    d = describe(effort_limit={"ff_.*": 0.5, "th_j2": 20.0, "default": 1.5})  # N·m; N for the prismatic joint
    assert d.effort_limits == (0.5, 0.5, 1.5, 20.0)
    np.testing.assert_array_equal(d.effort_limits_array, [0.5, 0.5, 1.5, 20.0])


@pytest.mark.parametrize(
    ("key", "bad", "says"),
    [
        ("effort_limit", 0.0, "a finite torque > 0 N·m per joint, got th_j1=0.0; give the actuator's data-sheet value"),
        ("effort_limit", -1.0, "a finite torque > 0 N·m per joint, got th_j1=-1.0; give the actuator's data-sheet"),
        ("armature", -0.001, "a finite inertia >= 0 kg·m² per joint, got th_j1=-0.001; give the actuator's reflected"),
        ("armature", -1.0, "a finite inertia >= 0 kg·m² per joint, got th_j1=-1.0; give the actuator's reflected"),
    ],
)
def test_an_actuator_value_out_of_range_names_the_joint(key, bad, says):
    with pytest.raises(AssetError, match=re.escape(f"hand 'mini': {key} must be {says}")):
        describe(**{key: {"th_j1": bad, "default": 1.0}})


@pytest.mark.parametrize(("key", "bad"), [("effort_limit", float("inf")), ("armature", float("nan"))])
def test_a_non_finite_actuator_value_is_refused_where_the_file_is_read(key, bad):
    with pytest.raises(AssetError, match=rf"{key}.dict\[str,float\].th_j1: Input should be a finite number"):
        describe(**{key: {"th_j1": bad, "default": 1.0}})


def test_armature_is_optional_and_expanded_per_joint():
    d = describe()
    assert d.armature == ()  # the file gives none: every engine keeps its default, 0
    np.testing.assert_array_equal(d.armature_array, np.zeros(4))
    d = describe(armature={"ff_.*": 0.001, "default": 0.0})  # kg·m²
    assert d.armature == (0.001, 0.001, 0.0, 0.0)


def test_a_hand_without_armature_keeps_its_dataset_identity_and_one_with_it_names_it():
    """describe_hand adds ``armature[J]`` keys only for a hand that declares armature: a dataset of a hand without
    (the Allegro's, written before the field existed) still matches its hand."""
    from ges_core.dataset.hands import describe_hand

    assert not any(k.startswith("armature[") for k in describe_hand(describe()))
    fields = describe_hand(describe(armature={"default": 0.002}))
    assert {k: v for k, v in fields.items() if k.startswith("armature[")} == {
        f"armature[{j}]": 0.002 for j in ("ff_j1", "ff_j2", "th_j1", "th_j2")
    }


def test_the_built_in_hands_declare_their_actuators():
    """Allegro: Isaac Lab's 0.5 N·m everywhere; Shadow: the MJCF actuators' forcerange, J0 as its leader J1."""
    from ges_core.registry import load_registry

    registry = load_registry()
    allegro = registry.build_hand("allegro").description
    assert allegro.effort_limits == (0.5,) * 16
    shadow = registry.build_hand("shadow").description
    limits = dict(zip(shadow.joint_names, shadow.effort_limits, strict=True))
    assert (limits["WRJ1"], limits["THJ4"], limits["THJ0"], limits["FFJ3"]) == (4.785, 2.3722, 0.81, 0.9)
    assert all(limits[f"{f}J0"] == limits[f"{f}J1"] == 0.7245 for f in ("FF", "MF", "RF", "LF"))


def test_pattern_matching_nothing_names_the_table():
    with pytest.raises(AssetError, match=r"mini.pd_damping: pattern 'lf_.\*' matches no joint"):
        describe(pd_damping={"lf_.*": 1.0, "default": 0.1})


# -- joints and limits --------------------------------------------------------------------
def test_limits_come_from_the_urdf_in_joint_names_order():
    assert urdf_joint_limits(URDF) == {
        "ff_j1": (-0.2, 1.5),
        "ff_j2": (0.0, 1.0),
        "th_j1": (-1.0, 1.0),
        "th_j2": (0.0, 0.02),
    }
    d = describe(joint_names=["th_j2", "ff_j1", "th_j1", "ff_j2"])
    assert d.joint_limits == ((0.0, 0.02), (-0.2, 1.5), (-1.0, 1.0), (0.0, 1.0))
    assert d.open_pose == (0.0, 0.1, -0.5, 0.1)  # per-joint tables follow joint_names
    assert d.base_link == "palm"


def test_unknown_joint_names():
    with pytest.raises(
        AssetError,
        match=r"hand 'mini': joint_names must list every movable URDF joint once: not in the URDF \['lf_j1'\]",
    ):
        describe(joint_names=["ff_j1", "ff_j2", "th_j1", "lf_j1"])


def test_fixed_joints_are_not_hand_joints():
    with pytest.raises(AssetError, match=r"not in the URDF \['ff_tip'\]"):
        describe(joint_names=[*JOINTS, "ff_tip"])


@pytest.mark.parametrize(
    "joint",
    [
        '<joint name="th_j2" type="continuous"><parent link="t1"/><child link="t2"/><axis xyz="0 0 1"/></joint>',
        '<joint name="th_j2" type="revolute"><parent link="t1"/><child link="t2"/>'
        '<limit effort="1" velocity="1"/></joint>',
    ],
)
def test_unlimited_joint_is_an_error(joint):
    start = URDF.index('<joint name="th_j2"')
    urdf = URDF[:start] + joint + URDF[URDF.index("</joint>", start) + len("</joint>") :]
    with pytest.raises(
        AssetError, match=r"hand 'mini': joints \['th_j2'\] have no limits in the URDF; give each a <limit>"
    ):
        describe(urdf_text=urdf)
    assert describe(urdf_text=urdf, strict=False).joint_limits[3] == (0.0, 0.0)  # the linter reports it instead


# -- file-level errors --------------------------------------------------------------------
def test_unknown_key_and_missing_key_are_reported_with_paths():
    with pytest.raises(AssetError, match=r"invalid description of hand 'mini': .*colour: Extra inputs"):
        describe(colour="red")
    with pytest.raises(AssetError, match=r"fingers.0.tip_link: Field required"):
        describe(YAML.replace(", tip_link: f_tip", "", 1))
    with pytest.raises(AssetError, match=r"middle_finger_length: Input should be greater than 0"):
        describe(middle_finger_length=0.0)


def test_yaml_that_is_not_a_mapping():
    with pytest.raises(AssetError, match="hand description must be a YAML mapping"):
        describe("- a\n- b\n")
    with pytest.raises(AssetError, match="hand description is not valid YAML"):
        describe("name: [unclosed\n")


def test_overrides_replace_top_level_keys():
    d = describe(scale=1.25, wrist={"link": "f1", "palm_normal": [0, 1, 0], "finger_direction": [0, 0, 1]})
    assert d.scale == 1.25 and d.wrist.link == "f1" and d.wrist.palm_normal == (0.0, 1.0, 0.0)


# -- HandDescription helpers (ges_core/hand.py) -------------------------------------------
def test_apply_couplings_sets_followers_then_clips():
    d = describe()
    q = np.array([[1.2, 0.9, 0.3, 0.01], [1.5, 0.0, 2.0, 0.05]])
    out = d.apply_couplings(q)
    np.testing.assert_allclose(out[:, 1], [0.6, 0.75])  # ratio 0.5 of the leader
    np.testing.assert_allclose(out[1, 2:], [1.0, 0.02])  # clipped to the URDF limits
    np.testing.assert_allclose(out[0, [0, 2, 3]], q[0, [0, 2, 3]])
    assert q[0, 1] == 0.9  # the input is not modified


def test_finger_for_slot_uses_slot_fill():
    d = describe()
    assert d.finger_for_slot("index").name == "ff"
    assert d.finger_for_slot("thumb").name == "th"
    assert d.finger_for_slot("little") is d.finger("ff")
    assert d.slot_tip_links == ("t_tip", "f_tip", "f_tip", "f_tip", "f_tip")
    assert [s for s in FINGER_SLOTS] == ["thumb", "index", "middle", "ring", "little"]


def test_finger_for_slot_without_a_rule():
    d = describe(slot_fill={"middle": "ff"})
    with pytest.raises(
        KeyError, match=r"unknown finger slot 'ring' in hand 'mini' \(no finger and no slot_fill rule\)"
    ):
        d.finger_for_slot("ring")
    with pytest.raises(KeyError, match=r"unknown finger 'lf' in hand 'mini'. Known fingers: ff, th"):
        d.finger("lf")


def test_closed_pose_moves_finger_joints_toward_their_far_limit():
    d = describe(couplings=[])
    closed = d.closed_pose(0.5)
    open_ = np.array(d.open_pose)
    far = np.array([1.5, 1.0, 1.0, 0.02])  # th_j1 open at -0.5: the upper limit is farther
    np.testing.assert_allclose(closed, open_ + 0.5 * (far - open_))


def test_joint_index_and_sizes():
    d = describe()
    assert d.num_joints == 4 and d.limits_array.shape == (4, 2)
    assert d.joint_index(["th_j2", "ff_j1"]).tolist() == [3, 0]
    assert d.tip_links == ("f_tip", "t_tip")
    assert d.finger("ff").tip_offset == (0.01, 0.0, 0.0)


def test_joint_names_must_list_each_movable_joint_once():
    with pytest.raises(AssetError, match=r"repeated \['ff_j1'\].*missing \['ff_j2'\]"):
        describe(joint_names=["ff_j1", "ff_j1", "th_j1", "th_j2"])  # ff_j1 twice, ff_j2 missing


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"couplings": [{"follower": "nope", "leader": "ff_j1"}]}, "coupling names unknown joint 'nope'"),
        ({"slot_fill": {"little": "lf"}}, "slot_fill: 'little' -> unknown finger 'lf'"),
    ],
)
def test_references_to_unknown_names_fail_when_parsed(overrides, message):
    with pytest.raises(AssetError, match=message):
        describe(**overrides)


def test_description_is_hashable():
    assert hash(describe()) == hash(describe())


def test_pad_normal_is_normalized_and_a_zero_one_is_refused():
    d = describe(YAML.replace("tip_offset: [0.01, 0, 0]}", "tip_offset: [0.01, 0, 0], pad_normal: [2, 0, 0]}"))
    assert d.finger("ff").pad_normal == (1.0, 0.0, 0.0)
    assert d.finger("th").pad_normal is None  # not declared: retargeting aims the tip point only
    with pytest.raises(AssetError, match=r"fingers\.0\.pad_normal: .*must be a non-zero direction"):
        describe(YAML.replace("tip_offset: [0.01, 0, 0]}", "tip_offset: [0.01, 0, 0], pad_normal: [0, 0, 0]}"))
