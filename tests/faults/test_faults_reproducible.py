"""Issue 10, point 8: record files are byte-reproducible. Wall-clock times live beside each record
(``<record>.timing.json``), so the same seed gives the same record files and a dataset can be checked by hash;
readers (``ges dataset info``, Table 1) take the times from there, and a record without them reads as times unknown.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import pytest
from test_dataset import CONFIG, make_record

from ges_core import cli
from ges_core.dataset import DatasetWriter, StepOutcome, open_dataset, record_relpath, validate_dataset
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.table import format_table, table_rows

OBJECTS = ["procedural/box/000", "procedural/cube/000", "pybullet/classic/domino"]
"""Two grasps that reach validation, one object that fails its contact step."""
QUICK = SynthesisConfig.model_validate(
    {"refine_sim": "pybullet", "validate_sims": ["pybullet"], "validate": {"hold_steps": 60}}
)


def hashes(root: Path, pattern: str = "records/**/*.npz") -> dict[str, str]:
    """Relative file -> SHA-256 of its bytes."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.glob(pattern)}


def timing_file(root: Path, object_id: str, hand: str = "shadow") -> Path:
    return root / record_relpath(object_id, hand).replace(".npz", ".timing.json")


def slower(record, factor: float):
    """``record`` as if every step had taken ``factor`` times as long."""
    steps = {name: replace(s, seconds=s.seconds * factor) for name, s in record.steps.items()}
    return replace(record, steps=steps, setup_seconds={k: v * factor for k, v in record.setup_seconds.items()})


def test_the_same_record_with_other_times_is_the_same_file(tmp_path):
    for name, factor in (("a", 1.0), ("b", 3.0)):
        with DatasetWriter(tmp_path / name, CONFIG) as writer:
            for oid in ("procedural/box/000", "procedural/mug/001"):
                writer.add(slower(make_record(oid), factor))
    assert hashes(tmp_path / "a") == hashes(tmp_path / "b") and len(hashes(tmp_path / "a")) == 2
    a, b = (json.loads(timing_file(tmp_path / n, "procedural/box/000").read_text()) for n in "ab")
    assert b["steps"]["contacts"] == pytest.approx(3 * a["steps"]["contacts"])
    assert (
        a["record_sha256"]
        == b["record_sha256"]
        == hashes(tmp_path / "a")[record_relpath("procedural/box/000", "shadow")]
    )
    assert open_dataset(tmp_path / "b").get("procedural/box/000", "shadow").steps["contacts"].seconds == pytest.approx(
        b["steps"]["contacts"]
    )


@pytest.mark.sim
def test_two_runs_with_the_same_seed_give_byte_identical_records(tmp_path):
    """The issue's probe: bit-identical arrays, never identical files (the times were inside)."""
    for name in ("one", "two"):
        run_synthesis(OBJECTS, ["allegro"], QUICK, tmp_path / name)
    one, two = hashes(tmp_path / "one"), hashes(tmp_path / "two")
    assert len(one) == 3 and one == two
    assert hashes(tmp_path / "one", "records/**/*.timing.json") != hashes(tmp_path / "two", "records/**/*.timing.json")
    for record in open_dataset(tmp_path / "two"):  # the times are there, beside the records
        assert record.total_seconds is not None and record.total_seconds > 0


@pytest.mark.sim
def test_a_resumed_run_makes_the_same_file_again(tmp_path):
    root = tmp_path / "ds"
    run_synthesis(OBJECTS, ["allegro"], QUICK, root)
    before = hashes(root)
    lost = record_relpath("procedural/cube/000", "allegro")
    (root / lost).unlink()
    report = run_synthesis(OBJECTS, ["allegro"], QUICK, root)
    assert report.written == [("procedural/cube/000", "allegro")] and hashes(root) == before
    assert validate_dataset(root) == []


def test_a_record_without_its_times_reads_as_times_unknown(tmp_path, capsys):
    root = tmp_path / "ds"
    with DatasetWriter(root, CONFIG) as writer:
        for oid in ("procedural/box/000", "procedural/mug/001"):
            writer.add(make_record(oid, hand="allegro"))
    timing_file(root, "procedural/box/000", "allegro").unlink()  # e.g. killed between the two writes
    ds = open_dataset(root)
    box = ds.get("procedural/box/000", "allegro")
    assert box.total_seconds is None and box.setup_seconds == {}
    assert all(s.seconds is None for s in box.steps.values()) and all(
        v.seconds is None for v in box.validations.values()
    )
    assert ds.notes == ("1 record(s) have no usable timing file: their times are unknown",)
    assert validate_dataset(root) == []  # a record without times is whole
    table = format_table(table_rows(ds))  # Table 1: the rates count both records, the times the known one
    assert "| allegro | sapien | 2 | 100.0 % (2/2), " in table
    assert cli.main(["dataset", "info", str(root)]) == 0
    assert "2/2 100.0%" in capsys.readouterr().out


def test_a_timing_file_of_another_record_is_not_used(tmp_path):
    root = tmp_path / "ds"
    with DatasetWriter(root, CONFIG) as writer:
        writer.add(make_record("procedural/box/000"))
        writer.add(make_record("procedural/mug/001"))
    box, mug = timing_file(root, "procedural/box/000"), timing_file(root, "procedural/mug/001")
    box.write_text(mug.read_text())  # a stale timing file: it names another record's bytes
    assert open_dataset(root).get("procedural/box/000", "shadow").total_seconds is None
    assert validate_dataset(root) == [
        f"{box.relative_to(root).as_posix()}: belongs to another version of the record (record_sha256 differs) "
        "(the record's times are unknown)"
    ]
    box.write_text("{")
    assert validate_dataset(root)[0].startswith(f"{box.relative_to(root).as_posix()}: unreadable (")


def test_table_1_and_info_take_the_times_from_the_timing_files(tmp_path, capsys):
    root = tmp_path / "ds"
    with DatasetWriter(root, CONFIG) as writer:
        record = make_record("procedural/box/000", hand="allegro")
        times = (0.25, 0.5, 1.5, 2.0, 4.0)  # the last: the robust trials, counted apart from the total
        steps = {name: StepOutcome(ok=True, seconds=t) for name, t in zip(record.steps, times, strict=True)}
        writer.add(replace(record, steps=steps))
    assert json.loads(timing_file(root, "procedural/box/000", "allegro").read_text())["steps"]["refinement"] == 1.5
    (row,) = table_rows(open_dataset(root))
    assert row.steps["refinement"].median == 1.5 and row.total_median == 4.25 and row.validation_median == 2.0
    assert row.robust_median == 4.0
    assert cli.main(["dataset", "info", str(root)]) == 0
    assert "1/1 100.0% 1.500 s" in capsys.readouterr().out
