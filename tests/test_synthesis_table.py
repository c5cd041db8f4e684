"""The run table's validated and robust columns: a count when the step was on, "not run" only when it was off."""

from __future__ import annotations

from dataclasses import replace

from test_dataset import make_record

from ges_core.dataset import NOT_RUN, StepOutcome
from ges_core.synthesis.run.table import format_table, table_rows

OFF = StepOutcome(ok=False, reason=NOT_RUN)


def _switched_off(record, *steps: str):
    """``record`` as a run with ``steps`` off writes it: those steps NOT_RUN where the record reached them."""
    return replace(record, steps={**record.steps, **{s: OFF for s in steps if record.steps[s].reason != "skipped"}})


def _cells(records) -> tuple[str, str]:
    """(validated, robust) cells of the one table row."""
    (row,) = table_rows(records)
    line = format_table([row]).splitlines()[2].split(" | ")
    return line[6], line[7]


def test_a_step_switched_off_reads_not_run():
    records = [make_record("procedural/box/000"), make_record("procedural/cube/000", fail_at="contacts")]
    assert _cells([_switched_off(r, "validation", "robust") for r in records]) == ("not run", "not run")
    assert _cells([_switched_off(r, "robust") for r in records]) == ("1/2 (50.0 %)", "not run")
    assert _cells(records) == ("1/2 (50.0 %)", "1/2 (50.0 %)")


def test_a_step_that_was_on_but_reached_by_no_record_reads_zero():
    """Every record failed before validation: SKIPPED, not NOT_RUN, so the step was on and validated none."""
    records = [make_record("procedural/box/000", fail_at="refinement")]
    assert _cells(records) == ("0/1 (0.0 %)", "0/1 (0.0 %)")


def test_agreement_rates_count_grasps_judged_alike_by_every_simulator():
    from ges_core.dataset import SimVerdict
    from ges_core.synthesis.run.table import agreement_rates

    def judged(oid, hand, *successes):
        verdicts = {sim: SimVerdict(success=ok, reason="success" if ok else "dropped") for sim, ok in successes}
        return replace(make_record(oid, hand=hand), validations=verdicts)

    records = [
        judged("procedural/box/000", "allegro", ("sapien", True), ("pybullet", True)),
        judged("procedural/cube/000", "allegro", ("sapien", True), ("pybullet", False)),
        judged("procedural/can/000", "allegro", ("sapien", False), ("pybullet", False)),
        judged("procedural/box/000", "shadow", ("sapien", True)),  # one simulator: not counted
    ]
    rates = agreement_rates(records)
    assert list(rates) == ["allegro"]
    assert rates["allegro"] == {"grasps": 3, "agree": 2, "sims": ["pybullet", "sapien"], "rate": 2 / 3}


def test_the_run_table_says_which_pairs_went_on_to_the_other_strategy():
    note = {"strategy": "vertical", "first_attempt": 16, "kept": False, "reason": "contacts: no_graspable_width"}
    went_on = replace(make_record("procedural/can/000"), extra={"other_strategy": note})
    records = [make_record("procedural/box/000"), went_on]
    text = format_table(table_rows(records))
    assert "shadow              tried 1 of 2, kept 0; not kept: contacts: no_graspable_width x1" in text
    assert "other grasp strategy" not in format_table(table_rows(records[:1]))  # no pair went on: no block


def test_the_per_simulator_lines_keep_their_columns_for_a_long_hand_name():
    """A hand name longer than the column (``ability_src``, 11 letters) ran into the simulator's name."""
    from ges_core.dataset.summary import SimStats, format_sim_stats

    def stats(hand: str) -> SimStats:
        return SimStats(hand, "sapien", 2, 1, None, 0, None, None, {})

    lines = format_sim_stats([stats("allegro"), stats("a_hand_with_a_long_name")], {}).splitlines()[1:]
    for line in lines:  # the header, then one row per hand: each splits into hand, simulator, validated, ...
        assert len(line.split()) >= 3 and line.split()[1] in ("simulator", "sapien"), lines
    assert len({line.index("sapien") for line in lines[1:]}) == 1  # the engine's column lines up
