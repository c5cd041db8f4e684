"""Record version 3 in the dataset: robust verdicts stored and read back, counted by ``ges dataset info``, and
version-2 datasets (made before robust validation) still opened, validated and summarized."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_dataset import CONFIG, assert_same, make_record

from ges_core import cli
from ges_core.dataset import (
    NOT_RUN,
    TOTAL_STEPS,
    DatasetWriter,
    StepOutcome,
    open_dataset,
    record_relpath,
    summarize,
    validate_dataset,
)
from ges_core.dataset.checks import record_problems
from ges_core.dataset.record import read_raw, record_from_bytes, record_to_bytes, record_to_raw

DATASET_V2 = Path(__file__).parent / "data" / "dataset_v2"
"""Four records written by the version-2 code (``ges synth``, Allegro and Shadow, SAPIEN and PyBullet verdicts)."""


def test_version_2_dataset_opens_validates_and_reads_as_not_robust_checked():
    assert json.loads((DATASET_V2 / "manifest.json").read_text())["version"] == 2
    assert validate_dataset(DATASET_V2) == []
    records = list(open_dataset(DATASET_V2))
    assert len(records) == 4 and {r.hand for r in records} == {"allegro", "shadow"}
    for record in records:
        meta, _ = read_raw((DATASET_V2 / record_relpath(record.object_id, record.hand)).read_bytes())
        assert meta["version"] == 2 and "robust" not in meta["steps"]
        assert record.steps["robust"] == StepOutcome(ok=False, reason=NOT_RUN, seconds=None)
        assert record.success == all(record.steps[s].ok for s in TOTAL_STEPS) and not record.robust
        assert record.total_seconds > 0  # the timing file of version 2 still gives the times
        assert all(
            v.trials == () and v.robustness is None and v.robust_seconds == 0.0 for v in record.validations.values()
        )
        assert all(a.robust == NOT_RUN for a in record.attempts)
        again = record_from_bytes(record_to_bytes(record))  # written again: version 3, reads the same
        assert record_to_raw(record)[0]["version"] == 3 and record_problems(*record_to_raw(record)) == []
        assert_same(again, record, times=False)
    text = summarize(open_dataset(DATASET_V2)).format()
    per_sim = [ln.split() for ln in text.splitlines() if ln.split()[1:2] in (["sapien"], ["pybullet"])]
    assert len(per_sim) == 4 and all(row[4:6] == ["not", "run"] for row in per_sim), text  # robust: not run


def test_robust_verdicts_round_trip_with_their_times(tmp_path):
    record = make_record("procedural/box/000", "allegro", fail_at="robust")
    assert record.steps["validation"].ok and not record.robust and record.robustness == 0.5
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        writer.add(record)
    back = open_dataset(tmp_path / "ds").get("procedural/box/000", "allegro")
    assert_same(back, record)
    verdict = back.validations["sapien"]
    assert [(t.name, t.success) for t in verdict.trials] == [("limits", True), ("mass_x2", False)]
    assert verdict.robust_seconds == 0.4 and back.steps["robust"].reason == "mass_x2"
    assert back.attempts[0].robust == "mass_x2" and back.attempts[0].robustness == 0.5
    assert back.total_seconds == pytest.approx(sum(back.steps[s].seconds for s in TOTAL_STEPS))


def test_info_counts_single_trial_and_robust_per_simulator(tmp_path, capsys):
    made = [
        make_record("procedural/box/000", "allegro"),
        make_record("procedural/box/001", "allegro", fail_at="robust"),
        make_record("procedural/box/002", "allegro", fail_at="validation"),
    ]
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for record in made:
            writer.add(record)
    summary = summarize(open_dataset(tmp_path / "ds"))
    stats = {s.simulator: s for s in summary.sims}
    assert set(stats) == {"sapien", "pybullet"}
    for s in stats.values():  # counted from the records, one by one
        assert (s.records, s.validated, s.robust, s.tried) == (3, 2, 1, 2)
        assert s.mean_robustness == pytest.approx(0.75) and s.trial_failures == {"mass_x2": 1}
    assert summary.agreement["allegro"] == {"grasps": 3, "single": 3, "robust_grasps": 3, "robust": 3,
                                            "sims": ["pybullet", "sapien"]}  # fmt: skip
    (group,) = summary.groups
    assert group.failures == {"validation": {"validation_failed": 1}, "robust": {"mass_x2": 1}}
    assert cli.main(["dataset", "info", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    assert "validation: validation_failed x1; robust: mass_x2 x1" in out
    (row,) = [line.split() for line in out.splitlines() if line.split()[:2] == ["allegro", "sapien"]]
    assert row[2:7] == ["2/3", "(66.7%)", "1/3", "(33.3%)", "0.750"] and row[-2:] == ["mass_x2", "x1"]
    assert "total time = contacts + retargeting + refinement + validation" in out


def test_info_counts_the_pairs_that_tried_the_other_strategy(tmp_path, capsys):
    from dataclasses import replace

    notes = [
        None,
        {"strategy": "vertical", "first_attempt": 16, "kept": True},
        {"strategy": "horizontal", "first_attempt": 16, "kept": False, "reason": "contacts: no_graspable_width"},
        {"strategy": "horizontal", "first_attempt": 3, "kept": False,
         "reason": "held no better: merit [2, 0.5] against the first strategy's [2, 0.75]"},
    ]  # fmt: skip
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for i, note in enumerate(notes):
            record = make_record(f"procedural/box/00{i}", "allegro")
            writer.add(record if note is None else replace(record, extra={"other_strategy": note}))
        writer.add(make_record("procedural/box/000", "shadow"))
    summary = summarize(open_dataset(tmp_path / "ds"))
    assert summary.second_passes["other_strategy"] == {  # shadow never went on: left out
        "allegro": {"records": 4, "tried": 3, "kept": 1,
                    "reasons": {"contacts: no_graspable_width": 1, "held no better": 1}},
    }  # fmt: skip
    assert cli.main(["dataset", "info", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    row = "allegro             tried 3 of 4, kept 1; not kept: contacts: no_graspable_width x1, held no better x1"
    assert row in out
    assert summary.second_passes["balanced_thumb"] == {} and "balanced" not in out


def test_info_counts_the_pairs_that_tried_a_balanced_thumb_or_a_lower_raise(tmp_path, capsys):
    from dataclasses import replace

    notes = [
        {"balanced_thumb": {"first_attempt": 16, "kept": True}},
        {"balanced_thumb": {"first_attempt": 16, "kept": False,
                            "reason": "held no better: merit [2, 0.5] against the first contacts' [2, 0.75]"},
         "low_raise": {"kept": False, "reason": "contacts: none lower"}},
    ]  # fmt: skip
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for i, extra in enumerate(notes):
            writer.add(replace(make_record(f"procedural/box/00{i}", "shadow"), extra=extra))
    summary = summarize(open_dataset(tmp_path / "ds"))
    assert summary.second_passes["other_strategy"] == {}
    assert summary.second_passes["balanced_thumb"] == {
        "shadow": {"records": 2, "tried": 2, "kept": 1, "reasons": {"held no better": 1}}
    }
    assert summary.second_passes["low_raise"] == {
        "shadow": {"records": 2, "tried": 1, "kept": 0, "reasons": {"contacts: none lower": 1}}
    }
    assert cli.main(["dataset", "info", str(tmp_path / "ds")]) == 0
    lines = capsys.readouterr().out.splitlines()
    at = lines.index("contacts with the thumb balancing the squeeze's torque (pairs that went on to it; why a second "
                     "pass was not kept):")  # fmt: skip
    assert lines[at + 1] == "  shadow              tried 2 of 2, kept 1; not kept: held no better x1"
    at = lines.index("the kept contacts retargeted with a lower raise (pairs that went on to it; why a second pass was "
                     "not kept):")  # fmt: skip
    assert lines[at + 1] == "  shadow              tried 1 of 2, kept 0; not kept: contacts: none lower x1"


def test_info_counts_the_records_whose_best_fit_was_left_out(tmp_path, capsys):
    """``extra["unreached_best_fit"]`` (the Stage 1 pipeline's note) counted per hand, records without it too."""
    from dataclasses import replace

    note = {"unreached_best_fit": [{"before_attempt": 0, "residual": 0.018}]}
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for i, extra in enumerate([note, {}, note]):
            writer.add(replace(make_record(f"procedural/box/00{i}", "shadow"), extra=extra))
        writer.add(make_record("procedural/box/000", "allegro"))
    summary = summarize(open_dataset(tmp_path / "ds"))
    assert summary.unreached_best == {"shadow": (2, 3)}  # the allegro's one record has none: left out
    assert cli.main(["dataset", "info", str(tmp_path / "ds")]) == 0
    lines = capsys.readouterr().out.splitlines()
    at = lines.index(
        "best fit left out for missing its contacts (the ranked placements that reached them tried instead):"
    )
    assert lines[at + 1] == "  shadow              2 of 3" and not lines[at + 2].startswith("  allegro")
