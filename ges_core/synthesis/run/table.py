"""A table like the paper's Table 1 from dataset records: per hand and simulator, per step success and time.

Success rates count attempted steps only (a step skipped after an earlier failure does not count), as
the paper's per-step rates do; ``validated`` is the share of *all* objects whose grasp passed the
physics lift-and-hold test. ``total`` is contacts + retargeting + refinement time per object. Times come
from the records' timing files (:mod:`ges_core.dataset.timing`); records whose times are unknown count for the
rates only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from ges_core.dataset import GraspRecord
from ges_core.dataset.summary import StepStats, step_stats

__all__ = ["TableRow", "agreement_rates", "format_table", "table_rows"]

TIMED_STEPS = ("contacts", "retargeting", "refinement")


@dataclass(frozen=True)
class TableRow:
    """One hand in one simulator."""

    hand: str
    simulator: str
    objects: int
    steps: dict[str, StepStats]
    validated: int
    """Records whose grasp passed physics validation."""
    validation_median: float | None
    total_median: float | None
    """Median over objects whose times are known of contacts + retargeting + refinement seconds."""
    failures: dict[str, int]
    """'step:reason' -> count."""

    def to_dict(self) -> dict:
        return asdict(self) | {"validated_rate": self.validated / self.objects if self.objects else None}


def table_rows(records: Iterable[GraspRecord]) -> list[TableRow]:
    """One row per (hand, simulator), sorted."""
    groups: dict[tuple[str, str], list[GraspRecord]] = {}
    for record in records:
        groups.setdefault((record.hand, record.simulator), []).append(record)
    return [_row(hand, sim, group) for (hand, sim), group in sorted(groups.items())]


def _row(hand: str, sim: str, records: list[GraspRecord]) -> TableRow:
    steps = {name: step_stats(r.steps[name] for r in records) for name in TIMED_STEPS}
    validation = [r.steps["validation"].seconds for r in records if r.steps["validation"].attempted]
    validation = [s for s in validation if s is not None]
    times = ([r.steps[s].seconds for s in TIMED_STEPS] for r in records)
    totals = [sum(t) for t in times if None not in t]
    failures: dict[str, int] = {}
    for r in records:
        if r.failed_step is not None:
            key = f"{r.failed_step}:{r.steps[r.failed_step].reason}"
            failures[key] = failures.get(key, 0) + 1
    return TableRow(
        hand=hand,
        simulator=sim,
        objects=len(records),
        steps=steps,
        validated=sum(bool(r.steps["validation"].ok) for r in records),
        validation_median=float(np.median(validation)) if validation else None,
        total_median=float(np.median(totals)) if totals else None,
        failures=dict(sorted(failures.items())),
    )


def agreement_rates(records: Iterable[GraspRecord]) -> dict[str, dict]:
    """Per hand: how often the validating simulators judged the same grasps alike (records validated in 2+)."""
    out: dict[str, dict] = {}
    for record in records:
        verdicts = record.validations
        if len(verdicts) < 2:
            continue
        same = len({v.success for v in verdicts.values()}) == 1
        row = out.setdefault(record.hand, {"grasps": 0, "agree": 0, "sims": sorted(verdicts)})
        row["grasps"] += 1
        row["agree"] += int(same)
    for row in out.values():
        row["rate"] = row["agree"] / row["grasps"]
    return out


def format_table(rows: list[TableRow]) -> str:
    """Markdown: per step success rate and median time per object, validated success, median total time."""
    head = "| hand | sim | objects | contacts | retargeting | refinement | validated | total (median) |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [_fmt_cell(r.steps[s]) for s in TIMED_STEPS]
        valid = f"{r.validated}/{r.objects} ({_pct(r.validated / r.objects if r.objects else None)})"
        total = "-" if r.total_median is None else f"{r.total_median:.2f} s"
        lines.append(f"| {r.hand} | {r.simulator} | {r.objects} | " + " | ".join(cells) + f" | {valid} | {total} |")
    return "\n".join(lines)


def _fmt_cell(cell: StepStats) -> str:
    if not cell.attempted:
        return "-"
    time = "-" if cell.median is None else f"{cell.median:.3f} s"
    return f"{_pct(cell.rate)} ({cell.ok}/{cell.attempted}), {time}"


def _pct(rate: float | None) -> str:
    return "-" if rate is None else f"{100 * rate:.1f} %"
