"""``ges demo``, ``ges synth`` and ``ges retarget`` end to end (tiny real runs: SAPIEN, 2 objects)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import ges_core.cli as cli
from ges_core.dataset import open_dataset, validate_dataset
from ges_core.synthesis import SynthesisConfig

FAST = ["-o", "synthesis.validate.hold_steps=60"]


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("demo")


def _demo(out, capsys) -> str:
    argv = ["demo", "--out", str(out), "--no-progress", "-o", "objects=2", "-o", "hands=[allegro]", *FAST]
    assert cli.main(argv) == 0
    return capsys.readouterr().out


@pytest.mark.sim
def test_demo_runs_end_to_end_then_resumes(demo_dir, capsys):
    text = _demo(demo_dir, capsys)
    assert "| hand | sim | objects | contacts | retargeting | refinement | validated (single trial) | robust" in text
    assert "| allegro | sapien | 2 |" in text
    assert "2 grasps synthesized, 0 already in" in text
    assert validate_dataset(demo_dir / "dataset") == []
    assert (demo_dir / "contact_sheet.png").is_file() and (demo_dir / "table.md").read_text().startswith("| hand")
    pictures = sorted((demo_dir / "pictures" / "allegro").glob("*.png"))
    assert [p.name for p in pictures] == ["procedural__box__000.png", "procedural__can__000.png"]
    again = _demo(demo_dir, capsys)
    assert "0 grasps synthesized, 2 already in" in again


@pytest.mark.sim
def test_demo_with_another_config_is_refused_unless_fresh(tmp_path, capsys):
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--no-progress", "-o", "objects=1", "-o", "hands=[allegro]", *FAST]
    assert cli.main([*argv, "-o", "pictures=false"]) == 0
    first = sorted(p.name for p in (out / "dataset").rglob("*"))
    capsys.readouterr()
    changed = [*argv, "-o", "pictures=false", "-o", "synthesis.attempts=1"]
    assert cli.main(changed) == 1
    assert f"attempts: {SynthesisConfig().attempts} -> 1" in capsys.readouterr().err
    assert cli.main([*changed, "--fresh"]) == 0
    text = capsys.readouterr().out
    assert f"moved the earlier {out} to {out}.old-1" in text and "1 grasps synthesized, 0 already in" in text
    assert sorted(p.name for p in (tmp_path / "demo.old-1" / "dataset").rglob("*")) == first  # nothing lost
    assert [r.object_id for r in open_dataset(out / "dataset")] == ["procedural/can/000"]


@pytest.mark.sim
def test_synth_continues_a_dataset_of_other_settings_only_when_asked(tmp_path, capsys):
    out = tmp_path / "ds"
    argv = ["synth", "--hands", "allegro", "--out", str(out), "--no-progress", "-o", "validate.hold_steps=60"]
    assert cli.main([*argv, "--objects", "procedural/can/000"]) == 0
    capsys.readouterr()
    more = [*argv, "--objects", "procedural/box/000", "-o", "attempts=1"]
    assert cli.main(more) == 1
    err = capsys.readouterr().err
    assert f"attempts: {SynthesisConfig().attempts} -> 1" in err and "ges synth --allow-config-change" in err
    assert [r.object_id for r in open_dataset(out)] == ["procedural/can/000"]  # the refused run wrote nothing
    assert cli.main([*more, "--allow-config-change"]) == 0
    records = {r.object_id: r for r in open_dataset(out)}
    assert sorted(records) == ["procedural/box/000", "procedural/can/000"]
    assert records["procedural/box/000"].run_config_hash != records["procedural/can/000"].run_config_hash
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["run_config"]["attempts"] == 1
    assert manifest["config_history"][0]["run_config"]["attempts"] == SynthesisConfig().attempts
    assert validate_dataset(out) == []  # both configs are named: every record's hash is known


@pytest.mark.sim
def test_retarget_table_counts_each_hands_records_once(tmp_path, capsys):
    """A source dataset that already holds target-hand records (retargeted in place before, or the demo's
    two hands) must not add them to the new ones in the printed table."""
    demo = tmp_path / "demo"
    argv = ["demo", "--out", str(demo), "--no-progress", "-o", "objects=1", "-o", "hands=[allegro]", *FAST]
    assert cli.main([*argv, "-o", "pictures=false"]) == 0
    source = demo / "dataset"
    assert cli.main(["retarget", "--from", "allegro", "--to", "shadow", str(source), "--no-progress"]) == 0  # in place
    assert "| shadow | sapien | 1 |" in capsys.readouterr().out
    assert sorted(r.hand for r in open_dataset(source)) == ["allegro", "shadow"]
    out = tmp_path / "again"
    assert (
        cli.main(["retarget", "--from", "allegro", "--to", "shadow", str(source), "--out", str(out), "--no-progress"])
        == 0
    )
    text = capsys.readouterr().out
    assert "| shadow | sapien | 1 |" in text and "| allegro | sapien | 1 |" in text
    assert [r.hand for r in open_dataset(out)] == ["shadow"]


@pytest.mark.sim
def test_retarget_reuses_stored_contacts(demo_dir, capsys, tmp_path):
    if not (demo_dir / "dataset").is_dir():
        _demo(demo_dir, capsys)
    out = tmp_path / "shadow"
    argv = ["retarget", "--from", "allegro", "--to", "shadow", str(demo_dir / "dataset"), "--out", str(out)]
    assert cli.main([*argv, "--no-progress"]) == 0
    table = capsys.readouterr().out
    assert "| allegro | sapien | 2 |" in table and "| shadow | sapien | 2 |" in table
    source, target = open_dataset(demo_dir / "dataset"), open_dataset(out)
    assert validate_dataset(out) == [] and len(target) == 2
    for record in target:
        stored = source.get(record.object_id, "allegro")
        assert record.hand == "shadow" and record.contacts_from == "allegro"
        np.testing.assert_array_equal(record.contacts.positions, stored.contacts.positions)
        assert record.steps["contacts"] == stored.steps["contacts"]
        assert record.joint_names != stored.joint_names  # a Shadow grasp, not a copy


def test_retarget_errors(tmp_path, capsys):
    from ges_core.dataset import DatasetWriter
    from ges_core.synthesis import SynthesisConfig

    DatasetWriter(tmp_path / "empty", SynthesisConfig().dump()).close()
    assert cli.main(["retarget", "--from", "shadow", "--to", "allegro", str(tmp_path / "empty")]) == 1
    assert "holds no record of hand 'shadow' (it holds: none)" in capsys.readouterr().err
    assert cli.main(["retarget", "--from", "shadow", "--to", "shadow", str(tmp_path / "empty")]) == 1
    assert "--from and --to are both 'shadow'" in capsys.readouterr().err


def test_unknown_object_and_bad_override(tmp_path, capsys):
    argv = ["synth", "--hands", "allegro", "--objects", "procedural/can/0000", "--out", str(tmp_path / "x")]
    assert cli.main(argv) == 1
    assert "unknown object 'procedural/can/0000'. Did you mean" in capsys.readouterr().err
    assert cli.main(["demo", "--out", str(tmp_path / "d"), "-o", "synthesis.pointz=5"]) == 1
    assert "synthesis.pointz" in capsys.readouterr().err
