"""Issue 10, point 5: the records are the truth, the manifest's index a cache of them. Opening a folder (the writer
on resume, the reader behind ``ges dataset info``) rebuilds the index from the record files: an entry that
disagrees with its record is repaired, a changed object id is indexed as what the file holds, a damaged record is
moved aside and made again, a missing or broken manifest is rebuilt, and only when the records were made with this
run's settings (each record carries its run config's hash).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from test_dataset import DATASET_V1, make_record

from ges_core import cli
from ges_core.dataset import DatasetWriter, open_dataset, record_relpath, summarize, validate_dataset
from ges_core.dataset.layout import config_hash, normalize_config
from ges_core.errors import ConfigError
from ges_core.synthesis import SynthesisConfig

CONFIG = SynthesisConfig().dump()
OTHER = SynthesisConfig(seed=1, points=512).dump()
"""The issue's probe: a resume with another seed and point count."""
RECORDS = [("procedural/box/000", None), ("procedural/mug/001", "retargeting"), ("procedural/can/002", None)]


@pytest.fixture
def root(tmp_path) -> Path:
    """A dataset of three Shadow records (one failed at retargeting) written with CONFIG."""
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for oid, fail_at in RECORDS:
            writer.add(make_record(oid, fail_at=fail_at))
    return tmp_path / "ds"


def manifest(root: Path) -> dict:
    return json.loads((root / "manifest.json").read_text())


def edit_manifest(root: Path, edit) -> None:
    data = manifest(root)
    edit(data)
    (root / "manifest.json").write_text(json.dumps(data))


def entry(data: dict, object_id: str) -> dict:
    return next(e for e in data["records"] if e["object_id"] == object_id)


def resume(root: Path, config: dict = CONFIG, **kw) -> DatasetWriter:
    """Open the folder as a resumed run would; the caller closes it."""
    return DatasetWriter(root, config, **kw)


def test_an_entry_that_disagrees_with_its_record_is_repaired_and_info_counts_the_records(root, capsys):
    def lie(data):
        box = entry(data, "procedural/box/000")
        box.update(success=False, failed_step="validation", split="unseen_object")
        box["steps"]["validation"] = [False, "dropped", 0.1]

    edit_manifest(root, lie)
    file = record_relpath("procedural/box/000", "shadow")
    assert any(
        p.startswith(f"{file}: manifest.json index disagrees with the record on [") for p in validate_dataset(root)
    )
    ds = open_dataset(root)  # the reader: the record's values, in memory
    assert entry({"records": ds.entries}, "procedural/box/000")["success"] is True
    assert any(n.startswith(f"manifest.json entry of {file} disagreed with its record on [") for n in ds.notes)
    summary = summarize(ds)
    assert summary.counts["split"] == {"train": 3} and summary.groups[0].succeeded == 2
    assert cli.main(["dataset", "info", str(root)]) == 0
    out = capsys.readouterr().out
    assert "by split:     train 3" in out and "2/3" in out and "disagreed with its record" in out
    with resume(root) as writer:  # the writer: repaired on disk
        assert any(
            "disagreed with its record on ['failed_step', 'split', 'steps', 'success']" in n for n in writer.recovered
        )
    assert validate_dataset(root) == [] and entry(manifest(root), "procedural/box/000")["success"] is True


def test_an_entry_whose_object_id_was_changed_leaves_one_entry_per_file(root):
    edit_manifest(root, lambda data: entry(data, "procedural/can/002").update(object_id="procedural/can/999"))
    with resume(root) as writer:
        assert writer.has("procedural/can/002", "shadow") and not writer.has("procedural/can/999", "shadow")
        assert any("as object 'procedural/can/999'" in n and "indexed as what it holds" in n for n in writer.recovered)
        if not writer.has("procedural/can/999", "shadow"):  # what a resumed run over can/999 does
            writer.add(make_record("procedural/can/999"))
    files = [e["file"] for e in manifest(root)["records"]]
    assert len(files) == len(set(files)) == 4 and validate_dataset(root) == []


def test_a_deleted_manifest_and_another_seed_and_point_count_is_refused(root):
    (root / "manifest.json").unlink()
    with pytest.raises(ConfigError) as info:
        resume(root, OTHER)
    text = str(info.value)
    assert text.startswith(f"dataset {root} has no usable manifest.json (manifest.json is missing) and holds records")
    assert f"this run's ({config_hash(normalize_config(OTHER))})" in text
    assert info.value.problems == [f"3 record(s) made with run config {config_hash(normalize_config(CONFIG))}"]
    assert not (root / "manifest.json").exists() and not (root / ".lock").exists()  # nothing written
    with resume(root) as writer:  # the settings the records were made with: rebuilt
        assert (
            len(writer) == 3 and "manifest.json rebuilt from the 3 record files (this run's config)" in writer.recovered
        )
    assert manifest(root)["run_config"] == normalize_config(CONFIG) and validate_dataset(root) == []


def test_a_deleted_manifest_with_another_config_is_accepted_when_allowed(root):
    (root / "manifest.json").unlink()
    with resume(root, OTHER, allow_config_change=True) as writer:
        assert len(writer) == 3
    data = manifest(root)
    assert data["run_config"] == normalize_config(OTHER)
    assert data["config_history"][0]["run_config_hash"] == config_hash(normalize_config(CONFIG))
    assert data["config_history"][0]["records"] == 3 and validate_dataset(root) == []


def test_a_manifest_naming_settings_no_record_was_made_with_is_refused(root):
    """A manifest replaced by hand (or by another run's): validate says so, a resume refuses."""
    edit_manifest(root, lambda data: data.update(run_config=normalize_config(OTHER)))
    problems = validate_dataset(root)
    assert len(problems) == 3 and all("which manifest.json does not name" in p for p in problems)
    with pytest.raises(ConfigError, match=r"holds records made with another run config than the one manifest.json"):
        resume(root, OTHER)


def test_a_truncated_listed_record_is_moved_aside_and_made_again(root, capsys):
    file = record_relpath("procedural/mug/001", "shadow")
    data = (root / file).read_bytes()
    (root / file).write_bytes(data[: len(data) // 2])
    assert [e["object_id"] for e in open_dataset(root).entries] == ["procedural/box/000", "procedural/can/002"]
    assert cli.main(["dataset", "info", str(root)]) == 0
    assert f"{file} cannot be used (left out): unreadable record" in capsys.readouterr().out
    with resume(root) as writer:
        assert not writer.has("procedural/mug/001", "shadow")
        assert any(n.startswith(f"moved {file} to .damaged/{file}: unreadable record") for n in writer.recovered)
        writer.add(make_record("procedural/mug/001", fail_at="retargeting"))
    assert (root / ".damaged" / file).read_bytes() == data[: len(data) // 2]
    assert (root / ".damaged" / file.replace(".npz", ".timing.json")).is_file()
    assert validate_dataset(root) == [] and len(list(open_dataset(root))) == 3


def test_a_corrupted_manifest_is_moved_aside_and_rebuilt(root):
    text = (root / "manifest.json").read_text()
    (root / "manifest.json").write_text(text[: len(text) // 2])
    with resume(root) as writer:
        assert len(writer) == 3
        assert writer.recovered[0].startswith("manifest.json could not be read (JSONDecodeError: ")
        assert writer.recovered[0].endswith("moved to .damaged/manifest.json")
    assert (root / ".damaged" / "manifest.json").read_text() == text[: len(text) // 2]
    assert validate_dataset(root) == [] and manifest(root)["run_config"] == normalize_config(CONFIG)


def test_a_corrupted_manifest_and_another_config_is_refused(root):
    (root / "manifest.json").write_text("{")
    with pytest.raises(ConfigError, match=r"has no usable manifest.json \(JSONDecodeError: .*\) and holds records"):
        resume(root, OTHER)
    assert (root / "manifest.json").read_text() == "{"  # left as it was


def test_a_version_1_folder_without_manifest_cannot_tell_its_settings(tmp_path):
    root = tmp_path / "v1"
    shutil.copytree(DATASET_V1, root)
    run_config = json.loads((root / "manifest.json").read_text())["run_config"]
    (root / "manifest.json").unlink()
    with pytest.raises(ConfigError, match=r"4 record\(s\) carry no run-config hash \(version 1"):
        resume(root, run_config)
    with resume(root, run_config, allow_config_change=True) as writer:
        assert len(writer) == 4
    assert manifest(root)["config_history"][0] == {
        "records": 4,
        "run_config": None,
        "run_config_hash": None,
        "until": manifest(root)["config_history"][0]["until"],
    }


def test_a_record_at_another_pairs_path_is_moved_home_or_aside(root):
    box, lost = record_relpath("procedural/box/000", "shadow"), record_relpath("procedural/lost/000", "shadow")
    shutil.copy(root / box, root / lost)  # a second copy of the box under another pair's name
    (root / "records" / "shadow" / "x.npz").write_bytes((root / box).read_bytes())
    (root / box).unlink()  # and the box's own file gone: the first misplaced copy goes home
    with resume(root) as writer:
        assert writer.has("procedural/box/000", "shadow") and len(writer) == 3
    assert (root / box).is_file() and not (root / lost).exists() and not (root / "records/shadow/x.npz").exists()
    assert len(list((root / ".damaged").rglob("*.npz"))) == 1 and validate_dataset(root) == []


@pytest.mark.sim
def test_ges_synth_resumes_over_a_truncated_record_and_says_so(tmp_path, caplog):
    """The issue's probe: the resume stopped with an instruction to delete the file by hand."""
    out = tmp_path / "ds"
    argv = ["synth", "--objects", "procedural/box/000", "procedural/cube/000", "--hands", "allegro"]
    argv += ["--sim", "pybullet", "--no-progress", "-o", "validate.hold_steps=60", "--out", str(out)]
    assert cli.main(argv) == 0
    file = out / record_relpath("procedural/cube/000", "allegro")
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    caplog.clear()
    assert cli.main(argv) == 0
    assert file.read_bytes() == data  # made again, byte for byte
    notes = [r.getMessage() for r in caplog.records if r.getMessage().startswith("ges: note: ")]
    assert len(notes) == 1 and notes[0].startswith(f"ges: note: moved {file.relative_to(out)} to .damaged/")
    assert "unreadable record" in notes[0] and validate_dataset(out) == []
