"""``ges dataset info``: counts, per-step success rates and timing medians, from the index rebuilt from the records.

Times come from the records' timing files; a record whose times are unknown counts for the rates, not the times.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ges_core.dataset.record import STEPS, TOTAL_STEPS, StepOutcome
from ges_core.dataset.store import Dataset

__all__ = ["DatasetSummary", "GroupStats", "StepStats", "step_stats", "summarize"]

COUNT_FIELDS = ("hand", "simulator", "split", "category")


@dataclass(frozen=True)
class StepStats:
    """One step over a group of records: only attempted steps count (:attr:`StepOutcome.attempted`)."""

    ok: int
    attempted: int
    mean: float | None
    """Mean wall time of the attempted steps whose time is known, seconds (None if there is none)."""
    std: float | None
    median: float | None

    @property
    def rate(self) -> float | None:
        """ok / attempted, or None when nothing was attempted."""
        return self.ok / self.attempted if self.attempted else None


def step_stats(outcomes: Iterable[StepOutcome]) -> StepStats:
    """Successes, attempts and times (seconds) of the attempted ones among ``outcomes``."""
    tried = [o for o in outcomes if o.attempted]
    times = np.array([o.seconds for o in tried if o.seconds is not None], dtype=np.float64)
    if not times.size:
        return StepStats(sum(o.ok for o in tried), len(tried), None, None, None)
    return StepStats(
        sum(o.ok for o in tried), len(tried), float(times.mean()), float(times.std()), float(np.median(times))
    )


@dataclass(frozen=True)
class GroupStats:
    """Statistics of the records of one hand in one simulator (or of all records)."""

    label: str
    records: int
    succeeded: int
    """Records whose every step succeeded."""
    steps: dict[str, StepStats]
    median_total_seconds: float | None
    """Median over records whose times are known of the summed step times, seconds."""


@dataclass(frozen=True)
class DatasetSummary:
    """What ``ges dataset info`` prints."""

    root: str
    records: int
    counts: dict[str, dict[str, int]]
    """Field (hand, simulator, split, category) -> value -> number of records."""
    groups: tuple[GroupStats, ...]
    """One per (hand, simulator), then one over all records."""
    notes: tuple[str, ...]
    """Where the folder differs from its manifest (:attr:`Dataset.notes`)."""

    def format(self) -> str:
        """Human-readable text, one table row per group."""
        lines = [f"dataset {self.root}: {self.records} records"]
        for field in COUNT_FIELDS:
            counts = ", ".join(f"{k} {n}" for k, n in sorted(self.counts[field].items()))
            lines.append(f"  by {field + ':':<10} {counts or '-'}")
        lines += [f"  note: {n}" for n in self.notes]
        lines.append("success per step (succeeded/attempted, rate, median time):")
        header = f"  {'group':<20}" + "".join(f"{s:>26}" for s in STEPS) + f"{'all steps':>16}{'total time':>12}"
        lines.append(header)
        lines += [_row(g) for g in self.groups]
        return "\n".join(lines)


def _row(group: GroupStats) -> str:
    cells = "".join(f"{_step_cell(group.steps[s]):>26}" for s in STEPS)
    share = f"{group.succeeded}/{group.records}"
    total = "-" if group.median_total_seconds is None else f"{group.median_total_seconds:.3f} s"
    return f"  {group.label:<20}{cells}{share:>16}{total:>12}"


def _step_cell(stats: StepStats) -> str:
    if not stats.attempted:
        return "-"
    time = "-" if stats.median is None else f"{stats.median:.3f} s"
    return f"{stats.ok}/{stats.attempted} {100 * stats.rate:5.1f}% {time}"


def summarize(dataset: Dataset) -> DatasetSummary:
    """Summary of ``dataset`` from its index (rebuilt from the records when it was opened)."""
    entries = dataset.entries
    counts = {f: dict(Counter(str(e.get(f)) for e in entries)) for f in COUNT_FIELDS}
    pairs = sorted({(e["hand"], e["simulator"]) for e in entries})
    groups = [_group(f"{h} / {s}", [e for e in entries if (e["hand"], e["simulator"]) == (h, s)]) for h, s in pairs]
    if len(pairs) != 1:
        groups.append(_group("all", list(entries)))
    return DatasetSummary(str(dataset.root), len(entries), counts, tuple(groups), dataset.notes)


def _group(label: str, entries: list[dict]) -> GroupStats:
    steps = {name: _step_stats([e["steps"][name] for e in entries]) for name in STEPS}
    times = ([e["steps"][s][2] for s in TOTAL_STEPS] for e in entries)
    totals = [sum(t) for t in times if None not in t]
    median = float(np.median(totals)) if totals else None
    return GroupStats(label, len(entries), sum(bool(e["success"]) for e in entries), steps, median)


def _step_stats(outcomes: list[list]) -> StepStats:
    """``outcomes``: [ok, reason, seconds] triples as stored in the index."""
    return step_stats(StepOutcome(ok=bool(ok), reason=reason, seconds=seconds) for ok, reason, seconds in outcomes)
