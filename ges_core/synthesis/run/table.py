"""A table like the paper's Table 1 from dataset records: per hand and simulator, per step success and time.

Success rates count attempted steps only (a step skipped after an earlier failure does not count), as
the paper's per-step rates do; ``validated`` is the share of *all* objects whose grasp passed the paper's
single physics lift-and-hold trial, ``robust`` the share that also held every perturbation trial
(:mod:`ges_core.synthesis.physics.robust`). ``total`` is :data:`ges_core.dataset.TOTAL_STEPS` (contacts +
retargeting + refinement + the nominal validation) per object, the same meaning as ``ges dataset info``'s; the
robust trials have their own column. Below the table: the validation per simulator (single trial, robust,
cross-engine agreement) and the failure reasons per step. Times come from the records' timing files
(:mod:`ges_core.dataset.timing`); records whose times are unknown count for the rates only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace

import numpy as np

from ges_core.dataset import NOT_RUN, TOTAL_STEPS, GraspRecord
from ges_core.dataset.summary import (
    SECOND_PASSES,
    TOTAL_TIME,
    StepStats,
    agreement,
    failure_reasons,
    format_failures,
    format_second_pass,
    format_sim_stats,
    format_unreached_best,
    reason_meanings,
    second_pass_stats,
    sim_stats,
    step_stats,
    unreached_best_stats,
)

__all__ = ["TableRow", "agreement_rates", "format_table", "table_rows"]

TIMED_STEPS = ("contacts", "retargeting", "refinement")
"""The steps with a success-rate-and-time column of their own (validation and robust have theirs)."""


@dataclass(frozen=True)
class TableRow:
    """One hand in one simulator."""

    hand: str
    simulator: str
    objects: int
    steps: dict[str, StepStats]
    validated: int | None
    """Records whose grasp passed the paper's single physics validation trial; None when validation did not run."""
    validation_median: float | None
    total_median: float | None
    """Median over objects whose times are known of the :data:`TOTAL_STEPS` seconds."""
    failures: dict[str, int]
    """'step:reason' -> count (each record at its first failed step)."""
    robust: int | None = None
    """Records whose grasp also held every perturbation trial; None when robust validation did not run."""
    robust_median: float | None = None
    """Median seconds per object of the perturbation trials, every attempt's summed (objects whose trials ran)."""
    records: tuple[GraspRecord, ...] = ()
    """The row's records (for the per-simulator section; not in :meth:`to_dict`)."""

    def to_dict(self) -> dict:
        data = asdict(replace(self, records=()))
        data.pop("records")
        rate = lambda n: n / self.objects if self.objects and n is not None else None  # noqa: E731
        return data | {"validated_rate": rate(self.validated), "robust_rate": rate(self.robust)}


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
    robust = [r.steps["robust"].seconds for r in records if r.steps["robust"].attempted]
    robust = [s for s in robust if s is not None]
    times = ([r.steps[s].seconds for s in TOTAL_STEPS] for r in records)
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
        validated=sum(bool(r.steps["validation"].ok) for r in records) if _ran(records, "validation") else None,
        validation_median=float(np.median(validation)) if validation else None,
        total_median=float(np.median(totals)) if totals else None,
        failures=dict(sorted(failures.items())),
        robust=sum(r.robust for r in records) if _ran(records, "robust") else None,
        robust_median=float(np.median(robust)) if robust else None,
        records=tuple(records),
    )


def _ran(records: list[GraspRecord], step: str) -> bool:
    """False when the run had ``step`` switched off: no record attempted it and some record that reached it says
    NOT_RUN (a record that failed earlier says SKIPPED either way, so if none reached it, it counts as on)."""
    steps = [r.steps[step] for r in records]
    return any(s.attempted for s in steps) or not any(s.reason == NOT_RUN for s in steps)


def agreement_rates(records: Iterable[GraspRecord]) -> dict[str, dict]:
    """Per hand: how often the validating simulators judged the same grasps alike (records validated in 2+):
    ``{"grasps", "agree", "sims", "rate"}``, the single-trial part of :func:`ges_core.dataset.summary.agreement`."""
    return {
        hand: {"grasps": a["grasps"], "agree": a["single"], "sims": a["sims"], "rate": a["single"] / a["grasps"]}
        for hand, a in agreement(records).items()
    }


def format_table(rows: list[TableRow]) -> str:
    """Markdown: per step success rate and median time per object, validated (single trial) and robust shares,
    median total time and robust-trial time; then the validation per simulator, the failure reasons per step and the
    pairs that went on to the other grasp strategy."""
    head = (
        "| hand | sim | objects | contacts | retargeting | refinement | validated (single trial) | robust "
        "(all perturbations) | total (median) | robust trials (median, all attempts) |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [_fmt_cell(r.steps[s]) for s in TIMED_STEPS]
        valid, robust = _share(r.validated, r.objects), _share(r.robust, r.objects)
        total = "-" if r.total_median is None else f"{r.total_median:.2f} s"
        trials = "-" if r.robust_median is None else f"{r.robust_median:.2f} s"
        lines.append(
            f"| {r.hand} | {r.simulator} | {r.objects} | "
            + " | ".join(cells)
            + f" | {valid} | {robust} | {total} | {trials} |"
        )
    lines.append(f"\n{TOTAL_TIME}.")
    records = [rec for r in rows for rec in r.records]
    sims = sim_stats(records)  # () when no record was validated
    if sims:
        lines += ["", format_sim_stats(sims, agreement(records))]
    lines.append("\nfailure reasons per step (each object counted at its first failed step):")
    reasons = []
    for r in rows:
        failed = [(rec.failed_step, rec.steps[rec.failed_step].reason) for rec in r.records if rec.failed_step]
        lines.append(f"  {r.hand} / {r.simulator}: {format_failures(failure_reasons(failed))}")
        reasons += [reason for _, reason in failed]
    for key in SECOND_PASSES:
        lines += format_second_pass(second_pass_stats(records, key), key)
    lines += format_unreached_best(unreached_best_stats(records))
    lines += reason_meanings(reasons, sims)
    return "\n".join(lines)


def _share(count: int | None, total: int) -> str:
    if count is None:
        return "not run"
    return f"{count}/{total} ({_pct(count / total if total else None)})"


def _fmt_cell(cell: StepStats) -> str:
    if not cell.attempted:
        return "-"
    time = "-" if cell.median is None else f"{cell.median:.3f} s"
    return f"{_pct(cell.rate)} ({cell.ok}/{cell.attempted}), {time}"


def _pct(rate: float | None) -> str:
    return "-" if rate is None else f"{100 * rate:.1f} %"
