"""A dataset keeps each hand's description and hash, and refuses to resume with a changed hand."""

from __future__ import annotations

import json
import shutil

import pytest
from test_dataset import make_record

from ges_core.config import parse_model
from ges_core.dataset import DatasetWriter, open_dataset
from ges_core.dataset.hands import describe_hand, hand_differences, urdf_fields
from ges_core.errors import ConfigError
from ges_core.hand_yaml import description_from_yaml
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.tasks import RegistrySpec

from helpers_sim import ALLEGRO_YAML, allegro_urdf_source

FAST = {"robust": {"enabled": False}, "validate_sims": [], "attempts": 1}
"""One object through contacts, retargeting and refinement only (a few seconds)."""


def test_a_real_changed_gain_is_refused_and_named(tmp_path):
    cfg, out = parse_model(SynthesisConfig, FAST), tmp_path / "ds"
    run_synthesis(["procedural/box/000"], ["shadow"], cfg, out)
    stored = json.loads((out / "manifest.json").read_text())["hands"]["shadow"]
    assert stored["description"]["pd_stiffness[FFJ1]"] == 1.0 and len(stored["hash"]) == 16
    stiffer = RegistrySpec(overrides=('settings.hand.shadow.pd_stiffness={"WRJ[01]": 5.0, FFJ1: 2.0, default: 1.0}',))
    with pytest.raises(ConfigError) as err:
        run_synthesis(["procedural/box/000", "procedural/sphere/000"], ["shadow"], cfg, out, registry=stiffer)
    message = str(err.value)
    assert "hand 'shadow'" in message and "pd_stiffness[FFJ1]: 1.0 -> 2.0" in message
    assert "--out DIR" in message and "--fresh" in message
    assert err.value.problems == ["shadow: pd_stiffness[FFJ1]: 1.0 -> 2.0"]  # nothing else differs
    assert len(open_dataset(out)) == 1  # nothing written
    report = run_synthesis(["procedural/box/000"], ["shadow"], cfg, out)  # the hand as it was: resumes
    assert report.skipped == [("procedural/box/000", "shadow")]


def _entry(hash_: str, **fields) -> dict:
    return {"hash": hash_, "description": fields}


def test_writer_hand_rules(tmp_path):
    old = {"shadow": _entry("a" * 16, scale=1.0), "allegro": _entry("b" * 16, scale=1.3)}
    with DatasetWriter(tmp_path, {"k": 1}, hands=old) as w:
        w.add(make_record("procedural/box/0", "shadow"))
    new = {"shadow": _entry("c" * 16, scale=1.1), "allegro": _entry("d" * 16, scale=1.4)}
    with pytest.raises(ConfigError, match=r"hand 'shadow' \(1 record\(s\).*scale: 1.0 -> 1.1"):
        DatasetWriter(tmp_path, {"k": 1}, hands=new)
    # allegro has no record there: its new description is taken without a word
    with DatasetWriter(tmp_path, {"k": 1}, hands={"allegro": new["allegro"]}):
        pass
    manifest = open_dataset(tmp_path).manifest
    assert manifest["hands"] == {"shadow": old["shadow"], "allegro": new["allegro"]}
    with DatasetWriter(tmp_path, {"k": 1}, hands=new, allow_config_change=True):
        pass
    manifest = open_dataset(tmp_path).manifest
    assert manifest["hands"]["shadow"] == new["shadow"]
    assert [h["hands"] for h in manifest["hands_history"]] == [{"shadow": old["shadow"]}]
    with DatasetWriter(tmp_path, {"k": 1}):  # hands=None: stored entries kept, unchecked
        pass
    assert open_dataset(tmp_path).manifest["hands"]["shadow"] == new["shadow"]


def test_a_dataset_written_before_hand_hashes_opens_with_a_note(tmp_path):
    with DatasetWriter(tmp_path, {"k": 1}) as w:
        w.add(make_record("procedural/box/0", "shadow"))
    assert "hands" not in json.loads((tmp_path / "manifest.json").read_text())
    hands = {"shadow": _entry("a" * 16, scale=1.0)}
    with DatasetWriter(tmp_path, {"k": 1}, hands=hands) as w:
        assert any("cannot be checked" in note and "shadow" in note for note in w.recovered)
    assert open_dataset(tmp_path).manifest["hands"] == hands  # checked from now on
    with pytest.raises(ConfigError, match="scale: 1.0 -> 2.0"):
        DatasetWriter(tmp_path, {"k": 1}, hands={"shadow": _entry("b" * 16, scale=2.0)})


def test_description_fields_name_settings_couplings_and_per_joint_values():
    urdf = allegro_urdf_source().read_text()
    plain = describe_hand(description_from_yaml(ALLEGRO_YAML, urdf))
    tuned = describe_hand(
        description_from_yaml(
            ALLEGRO_YAML + "\nsettings: {validate: {min_squeeze: 0.3}}\n"
            "couplings: [{follower: joint_3.0, leader: joint_2.0, ratio: 1.0, offset: 0.1}]\n",
            urdf,
        )
    )
    assert hand_differences(plain, tuned) == [
        'couplings[joint_3.0]: <absent> -> ["joint_2.0", 1.0, 0.1]',
        "settings.validate.min_squeeze: <absent> -> 0.3",
    ]
    assert plain["joint_limits[joint_0.0]"] == [pytest.approx(-0.47), pytest.approx(0.47)]


def test_urdf_hash_follows_mesh_content_not_where_the_files_are(tmp_path):
    text = (
        '<robot name="r"><link name="a"><collision><geometry><mesh filename="m/a.obj"/></geometry></collision>'
        '<visual><geometry><mesh filename="m/a.obj"/></geometry></visual></link></robot>'
    )
    one, two = tmp_path / "one", tmp_path / "two"
    (one / "m").mkdir(parents=True)
    (one / "m" / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    shutil.copytree(one, two)
    absolute = text.replace("m/a.obj", str(two / "m" / "a.obj"))
    assert urdf_fields(text, one) == urdf_fields(absolute, tmp_path)  # same bytes, other folder, absolute path
    (two / "m" / "a.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    changed = hand_differences(urdf_fields(text, one), urdf_fields(text, two))
    assert [line.split(":")[0] for line in changed] == ["mesh[a/collision/0]", "mesh[a/visual/0]", "urdf"]
