"""``ges dataset info``: counts, per-step success rates, failure reasons and timing medians, from the index rebuilt
from the records, then the validation per simulator (the paper's single trial and robust validation) from the records.

Times come from the records' timing files; a record whose times are unknown counts for the rates, not the times.
"Total time" is the sum of :data:`~ges_core.dataset.record.TOTAL_STEPS` (contacts + retargeting + refinement +
validation's nominal trial); the robust trials are counted apart.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ges_core.dataset.reasons import reason_lines
from ges_core.dataset.record import HELD_NO_BETTER, NOT_RUN, STEPS, TOTAL_STEPS, GraspRecord, StepOutcome
from ges_core.dataset.store import Dataset

__all__ = [
    "TOTAL_TIME",
    "DatasetSummary",
    "GroupStats",
    "SimStats",
    "SECOND_PASSES",
    "StepStats",
    "agreement",
    "failure_reasons",
    "format_failures",
    "format_second_pass",
    "format_sim_stats",
    "format_unreached_best",
    "second_pass_stats",
    "reason_meanings",
    "sim_stats",
    "step_stats",
    "summarize",
    "unreached_best_stats",
]

TOTAL_TIME = "total time = " + " + ".join(TOTAL_STEPS) + " (the nominal trial), median per record; robust trials apart"
"""What "total time" means wherever it is printed (one meaning everywhere)."""

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
    """Median over records whose times are known of the summed :data:`TOTAL_STEPS` times, seconds."""
    failures: dict[str, dict[str, int]] = field(default_factory=dict)
    """Step -> failure reason -> records whose first failed step it is (:func:`failure_reasons`)."""


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
    sims: tuple[SimStats, ...] = ()
    """Per hand and validating simulator: single-trial and robust counts (:func:`sim_stats`)."""
    agreement: dict[str, dict] = field(default_factory=dict)
    """Per hand, cross-engine agreement (:func:`agreement`)."""
    second_passes: dict[str, dict[str, dict]] = field(default_factory=dict)
    """Per second pass (:data:`SECOND_PASSES`' keys), per hand, the pairs that went on to it
    (:func:`second_pass_stats`)."""
    unreached_best: dict[str, tuple[int, int]] = field(default_factory=dict)
    """Per hand, records whose best fit was left out for missing its contacts, and its records
    (:func:`unreached_best_stats`)."""

    def format(self) -> str:
        """Human-readable text, one table row per group."""
        lines = [f"dataset {self.root}: {self.records} records"]
        for name in COUNT_FIELDS:
            counts = ", ".join(f"{k} {n}" for k, n in sorted(self.counts[name].items()))
            lines.append(f"  by {name + ':':<10} {counts or '-'}")
        lines += [f"  note: {n}" for n in self.notes]
        lines.append(f"success per step (succeeded/attempted, rate, median time); {TOTAL_TIME}:")
        header = f"  {'group':<20}" + "".join(f"{s:>26}" for s in STEPS) + f"{'all steps':>16}{'total time':>12}"
        lines.append(header)
        lines += [_row(g) for g in self.groups]
        lines.append("failure reasons per step (each record counted at its first failed step):")
        lines += [f"  {g.label:<20}{format_failures(g.failures)}" for g in self.groups]
        for key, stats in self.second_passes.items():
            lines += format_second_pass(stats, key)
        lines += format_unreached_best(self.unreached_best)
        if self.sims:
            lines += ["", format_sim_stats(self.sims, self.agreement)]
        lines += reason_meanings([r for g in self.groups for step in g.failures.values() for r in step], self.sims)
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
    """Summary of ``dataset``: steps from its index (rebuilt from the records when it was opened), validation per
    simulator from the records themselves."""
    entries = dataset.entries
    counts = {f: dict(Counter(str(e.get(f)) for e in entries)) for f in COUNT_FIELDS}
    pairs = sorted({(e["hand"], e["simulator"]) for e in entries})
    groups = [_group(f"{h} / {s}", [e for e in entries if (e["hand"], e["simulator"]) == (h, s)]) for h, s in pairs]
    if len(pairs) != 1:
        groups.append(_group("all", list(entries)))
    records = list(dataset)
    return DatasetSummary(
        str(dataset.root),
        len(entries),
        counts,
        tuple(groups),
        dataset.notes,
        sim_stats(records),
        agreement(records),
        {key: second_pass_stats(records, key) for key in SECOND_PASSES},
        unreached_best_stats(records),
    )


SECOND_PASSES = {
    "other_strategy": "the other grasp strategy",
    "balanced_thumb": "contacts with the thumb balancing the squeeze's torque",
    "low_raise": "the kept contacts retargeted with a lower raise",
}
"""The Stage 1 pipeline's second passes by the ``extra`` key of their note, and what each tried."""


def second_pass_stats(records: Iterable[GraspRecord], key: str) -> dict[str, dict]:
    """Per hand, over the records whose pair went on to a second pass (``extra[key]``, the Stage 1 pipeline's note:
    a key of :data:`SECOND_PASSES`): ``{"records", "tried", "kept", "reasons"}``,
    ``reasons`` counting why a second pass was not kept (``step: reason``; "held no better" without its figures).
    Hands with no such record are left out."""
    out: dict[str, dict] = {}
    seen: Counter[str] = Counter()
    for record in records:
        seen[record.hand] += 1
        note = record.extra.get(key)
        if not isinstance(note, dict):
            continue
        row = out.setdefault(record.hand, {"records": 0, "tried": 0, "kept": 0, "reasons": Counter()})
        row["tried"] += 1
        row["kept"] += bool(note.get("kept"))
        if not note.get("kept"):
            reason = str(note.get("reason", "?"))
            row["reasons"][HELD_NO_BETTER if reason.startswith(HELD_NO_BETTER) else reason] += 1
    for hand, row in out.items():
        row["records"] = seen[hand]
        row["reasons"] = dict(row["reasons"].most_common())
    return out


def format_second_pass(stats: dict[str, dict], key: str) -> list[str]:
    """:func:`second_pass_stats` of ``key`` as text lines, a heading and one per hand; none when no pair went on."""
    if not stats:
        return []
    lines = [f"{SECOND_PASSES[key]} (pairs that went on to it; why a second pass was not kept):"]
    for hand, row in sorted(stats.items()):
        reasons = ", ".join(f"{k} x{n}" for k, n in row["reasons"].items()) or "-"
        lines.append(f"  {hand:<20}tried {row['tried']} of {row['records']}, kept {row['kept']}; not kept: {reasons}")
    return lines


UNREACHED_BEST = "unreached_best_fit"
"""The ``extra`` key of the Stage 1 pipeline's note on a best fit left out for missing its contacts."""


def unreached_best_stats(records: Iterable[GraspRecord]) -> dict[str, tuple[int, int]]:
    """Per hand, (records whose pair left its best fit out because it missed its contacts while later placements
    reached them: ``extra["unreached_best_fit"]``, records); hands with none left out are left out."""
    left: Counter[str] = Counter()
    seen: Counter[str] = Counter()
    for record in records:
        seen[record.hand] += 1
        left[record.hand] += bool(record.extra.get(UNREACHED_BEST))
    return {hand: (n, seen[hand]) for hand, n in sorted(left.items()) if n}


def format_unreached_best(stats: dict[str, tuple[int, int]]) -> list[str]:
    """:func:`unreached_best_stats` as text lines, a heading and one per hand; none when no best fit was left out."""
    if not stats:
        return []
    lines = ["best fit left out for missing its contacts (the ranked placements that reached them tried instead):"]
    return lines + [f"  {hand:<20}{n} of {total}" for hand, (n, total) in stats.items()]


def _group(label: str, entries: list[dict]) -> GroupStats:
    steps = {name: _step_stats([e["steps"][name] for e in entries if name in e["steps"]]) for name in STEPS}
    times = ([e["steps"][s][2] for s in TOTAL_STEPS] for e in entries)
    totals = [sum(t) for t in times if None not in t]
    median = float(np.median(totals)) if totals else None
    failed = [(e["failed_step"], e["steps"][e["failed_step"]][1]) for e in entries if e.get("failed_step")]
    return GroupStats(
        label, len(entries), sum(bool(e["success"]) for e in entries), steps, median, failure_reasons(failed)
    )


def failure_reasons(failed: Iterable[tuple[str, str]]) -> dict[str, dict[str, int]]:
    """Step -> reason -> count, steps in pipeline order, reasons by count (then name); ``failed``: one
    (first failed step, its reason) pair per failed record."""
    counts = Counter(failed)
    out: dict[str, dict[str, int]] = {}
    for step in STEPS:
        reasons = sorted(((r, n) for (s, r), n in counts.items() if s == step), key=lambda rn: (-rn[1], rn[0]))
        if reasons:
            out[step] = dict(reasons)
    return out


def reason_meanings(reasons: Iterable[str], sims: Iterable[SimStats] = ()) -> list[str]:
    """A blank line, ``what the reasons mean:`` and a line per distinct known reason of ``reasons`` (the steps'
    failure reasons) and of the perturbation trials that failed in ``sims`` (first-seen order;
    :mod:`ges_core.dataset.reasons`); [] when none is known."""
    lines = reason_lines([*reasons, *(t for s in sims for t in s.trial_failures)], indent="  ")
    return ["", "what the reasons mean:", *lines] if lines else []


def format_failures(failures: dict[str, dict[str, int]]) -> str:
    """``contacts: no_graspable_width x2; robust: mass_x2 x3, pose_1 x1`` (or ``none``)."""
    parts = [f"{step}: " + ", ".join(f"{r} x{n}" for r, n in reasons.items()) for step, reasons in failures.items()]
    return "; ".join(parts) or "none"


@dataclass(frozen=True)
class SimStats:
    """The validation of one hand's records in one validating simulator."""

    hand: str
    simulator: str
    records: int
    """Records of this hand (every one counts: a grasp that never reached validation was not validated)."""
    validated: int
    """The paper's single nominal trial held in this simulator."""
    robust: int | None
    """The nominal trial and every perturbation trial held in this simulator; None when robust validation did not
    run for any of these records (switched off, or records older than it)."""
    tried: int
    """Records whose perturbation trials ran in this simulator (their nominal trial held)."""
    mean_robustness: float | None
    """Mean robustness score (fraction of trials held) over the ``tried`` records; None if none."""
    robust_median: float | None
    """Median seconds of a record's perturbation trials (over ``tried`` records with known times)."""
    trial_failures: dict[str, int]
    """Perturbation -> records where it failed (every failed trial, not only the first)."""


def sim_stats(records: Iterable[GraspRecord]) -> tuple[SimStats, ...]:
    """One :class:`SimStats` per (hand, validating simulator) found in the records' ``validations``, sorted."""
    by_hand: dict[str, list[GraspRecord]] = {}
    for record in records:
        by_hand.setdefault(record.hand, []).append(record)
    out = []
    for hand, group in sorted(by_hand.items()):
        for sim in sorted({s for r in group for s in r.validations}):
            out.append(_sim_stats(hand, sim, group))
    return tuple(out)


def _sim_stats(hand: str, sim: str, records: list[GraspRecord]) -> SimStats:
    verdicts = [r.validations[sim] for r in records if sim in r.validations]
    tried = [v for v in verdicts if v.robustness is not None]
    times = [v.robust_seconds for v in tried if v.robust_seconds is not None]
    failures = Counter(t.name for v in tried for t in v.trials if not t.success)
    return SimStats(
        hand=hand,
        simulator=sim,
        records=len(records),
        validated=sum(v.success for v in verdicts),
        robust=sum(v.robust for v in verdicts) if any(_robust_ran(r) for r in records) else None,
        tried=len(tried),
        mean_robustness=float(np.mean([v.robustness for v in tried])) if tried else None,
        robust_median=float(np.median(times)) if times else None,
        trial_failures=dict(sorted(failures.items(), key=lambda kv: (-kv[1], kv[0]))),
    )


def _robust_ran(record: GraspRecord) -> bool:
    """Robust validation was on for this record (its step is not ``not_run``)."""
    step = record.steps.get("robust")
    return step is not None and (step.ok or step.reason != NOT_RUN)


def agreement(records: Iterable[GraspRecord]) -> dict[str, dict]:
    """Per hand, over records validated in 2+ simulators: how many got the same single-trial verdict in all
    (``single``) and, over those where robust validation ran, the same robust verdict (``robust`` of
    ``robust_grasps``); ``{"grasps", "single", "robust_grasps", "robust", "sims"}``."""
    out: dict[str, dict] = {}
    for record in records:
        verdicts = record.validations
        if len(verdicts) < 2:
            continue
        keys = {"grasps": 0, "single": 0, "robust_grasps": 0, "robust": 0, "sims": sorted(verdicts)}
        row = out.setdefault(record.hand, keys)
        row["grasps"] += 1
        row["single"] += len({v.success for v in verdicts.values()}) == 1
        if _robust_ran(record):
            row["robust_grasps"] += 1
            row["robust"] += len({v.robust for v in verdicts.values()}) == 1
    return out


def format_sim_stats(stats: Iterable[SimStats], agreements: dict[str, dict]) -> str:
    """The validation per simulator as text: single trial, robust, mean robustness, trial time, failed trials."""
    stats = list(stats)
    width = max([9, *(len(s.hand) for s in stats)]) + 1  # a long hand name still leaves a space before the engine
    lines = [
        "validation per simulator (validated = the paper's single nominal trial; robust = it and every perturbation "
        "trial held):",
        f"  {'hand':<{width}}{'simulator':<11}{'validated':>19}{'robust':>19}{'robustness':>12}{'trials (median)':>17}"
        "  failed trials",
    ]
    for s in stats:
        score = "-" if s.mean_robustness is None else f"{s.mean_robustness:.3f}"
        time = "-" if s.robust_median is None else f"{s.robust_median:.2f} s"
        failed = ", ".join(f"{k} x{n}" for k, n in s.trial_failures.items()) or "-"
        lines.append(
            f"  {s.hand:<{width}}{s.simulator:<11} {_share(s.validated, s.records):>18} "
            f"{_share(s.robust, s.records):>18}{score:>12}{time:>17}  {failed}"
        )
    for hand, row in sorted(agreements.items()):
        lines.append(
            f"  cross-engine agreement, {hand} ({' vs '.join(row['sims'])}): single trial "
            f"{_share(row['single'], row['grasps'])}, robust {_share(row['robust'], row['robust_grasps'])}"
        )
    return "\n".join(lines)


def _share(count: int | None, total: int) -> str:
    if count is None:
        return "not run"
    return f"{count}/{total} ({100 * count / total:.1f}%)" if total else "-"


def _step_stats(outcomes: list[list]) -> StepStats:
    """``outcomes``: [ok, reason, seconds] triples as stored in the index."""
    return step_stats(StepOutcome(ok=bool(ok), reason=reason, seconds=seconds) for ok, reason, seconds in outcomes)
