"""What the failure reasons mean (``ges_core.dataset.reasons``): every reason the pipeline's code can record has a
line, read from the code itself rather than from a list kept beside it, and ``ges dataset info`` / the run table
explain the reasons they count and only those."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

from test_dataset import CONFIG, make_record

import ges_core
from ges_core import cli
from ges_core.dataset import NOT_RUN, DatasetWriter
from ges_core.dataset.reasons import REASON_HELP, reason_help, reason_lines
from ges_core.synthesis.run.table import format_table, table_rows

ROOT = Path(ges_core.__file__).parent / "synthesis"
"""The Stage 1 pipeline's code: where a record's reasons are written (Stage 2's own reasons are other words)."""

RECORDED = [
    r"""_fail\(\s*"([a-z_]+)\"""",  # contact generation (generate.py)
    r"""reason="([a-z_]+)\"""",  # SynthesisError(..., reason=...), SimVerdict(..., reason=...)
    r"""StepOutcome\.failed\(\s*"([a-z_]+)\"""",  # a step's outcome set in the worker
    r"""failed_contacts\(\s*"([a-z_]+)\"""",  # the contact step's failure in the worker
]
"""How the pipeline's code writes a failure reason as a literal."""


def _reasons_in_code() -> set[str]:
    found: set[str] = set()
    for path in ROOT.rglob("*.py"):
        text = path.read_text()
        for pattern in RECORDED:
            found |= set(re.findall(pattern, text))
    return found


def test_every_reason_the_pipeline_records_has_a_line():
    from ges_core.synthesis.physics.refine import UNSTABLE_REST, refine_verdict
    from ges_core.synthesis.physics.validate import REASONS

    literal = _reasons_in_code()
    assert {"no_graspable_width", "bad_mesh", "unreachable", "degenerate_contacts", "unstable"} <= literal  # found
    verdicts = set(re.findall(r'return "([a-z_]+)"', inspect.getsource(refine_verdict))) - {"ok"}
    assert verdicts == {"penetration", "table_contact", "object_moved", "few_contacts"}
    recorded = literal | verdicts | (set(REASONS) - {"success"}) | {UNSTABLE_REST, NOT_RUN}
    missing = sorted(r for r in recorded if reason_help(r) is None)
    assert not missing, f"failure reasons without a line in ges_core/dataset/reasons.py: {missing}"


def test_every_perturbation_trial_has_a_line():
    from ges_core.objects.asset import ObjectAsset
    from ges_core.synthesis.physics.robust import RobustConfig, perturbations

    config = RobustConfig(drive_limits=True, mass_scales=(0.25, 3.0), friction_floor=0.65, pose_trials=12)
    asset = ObjectAsset(object_id="procedural/box/000", category="box", mesh_path=Path("box.obj"), collision=())
    names = [p.name for p in perturbations(config, 1.0, asset, seed=3)]
    assert names[:4] == ["limits", "mass_x0.25", "mass_x3", "friction_0.65"] and names[-1] == "pose_12"
    assert all(reason_help(n) is not None for n in names), names
    assert reason_help("mass_xlots") is None and reason_help("pose_") is None  # the patterns are whole names


def test_one_line_per_family_in_first_seen_order_and_unknown_reasons_left_out():
    lines = reason_lines(["mass_x2", "pose_1", "no_such_reason", "mass_x0.5", "pose_3", "mass_x2", "dropped"])
    assert [line.split(":")[0] for line in lines] == ["  mass_x2, mass_x0.5", "  pose_1, pose_3", "  dropped"]
    assert lines[2] == "  dropped: " + REASON_HELP["dropped"]
    assert reason_lines(["no_such_reason"]) == []


def test_dataset_info_and_the_run_table_explain_the_reasons_they_count(tmp_path, capsys):
    records = [
        make_record("procedural/box/000", "allegro"),
        make_record("procedural/box/001", "allegro", fail_at="robust"),  # reason mass_x2
        make_record("procedural/box/002", "allegro", fail_at="validation"),  # reason validation_failed: unknown
    ]
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for record in records:
            writer.add(record)
    assert cli.main(["dataset", "info", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    for text in (out, format_table(table_rows(records))):
        meanings = text.split("what the reasons mean:\n")[1].splitlines()
        assert meanings == ["  mass_x2: " + reason_help("mass_x2")], meanings  # the one known reason, once
    assert "what the reasons mean" not in format_table(table_rows(records[:1]))  # nothing failed: no block
