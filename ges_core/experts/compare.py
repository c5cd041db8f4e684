"""Is an expert above the scripted baseline, or only lucky? Paired comparison over objects, and pooling of runs.

With 4 episodes per object one episode moves a split's rate by 0.15-1.3 points, and two evaluation seeds of the
same checkpoints have put one expert 1.2 points above the baseline on train and then 0.5 below it
(docs/training.md). So a difference of rates is read with its uncertainty:

- :func:`pool_matrices`: matrices of the same objects and expert columns run with other seeds (``-o seed=1 -o
  env.randomization.seed=1``) add up to one with more episodes per cell.
- :func:`compare_to_baseline`: per expert and split, the difference of success rates to the baseline in points
  with a paired bootstrap interval over objects (both columns resampled with the same objects, so what the
  objects share cancels), and the objects where the expert's rate is above / below the baseline's. The verdict is
  ``above`` only when the whole interval is above 0, and none is given on fewer than :data:`MIN_OBJECTS` objects
  (a bootstrap over one object that held its one episode reads [+100, +100]: it cannot see the noise).
- :func:`held_out_oracle`: the oracle (best column per object) picked on one run's episodes and scored on
  another's. The oracle of a matrix picks each object's best column *on the episodes it is scored on*, so where the
  columns differ by noise it sits above every column without any column being better; the held-out oracle is
  what a perfect gate trained on the first run's outcomes would reach on fresh episodes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ges_core.errors import ConfigError
from ges_core.experts.gained import with_gained_settings
from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix
from ges_core.objects.splits import SPLITS

MIN_OBJECTS = 10
"""Fewest objects of a split for a verdict (the percentile bootstrap needs objects to resample)."""

__all__ = [
    "MIN_OBJECTS",
    "BaselineDifference",
    "HeldOutOracle",
    "column_list",
    "common_columns",
    "compare_to_baseline",
    "comparison_table",
    "held_out_oracle",
    "held_out_oracle_table",
    "pool_matrices",
    "select_columns",
]


@dataclass(frozen=True)
class BaselineDifference:
    """One expert against the baseline on one split (rates over every episode of the split's objects)."""

    expert: str
    split: str | None
    """train, unseen_object, unseen_category; None: every object."""
    objects: int
    """Objects with episodes in both columns (the only ones compared)."""
    points: float
    """Expert's success rate minus the baseline's, in percentage points."""
    low: float
    """Lower end of the bootstrap interval of ``points`` (percentile, ``level`` coverage)."""
    high: float
    """Upper end of that interval."""
    better: int
    """Objects where the expert's rate is above the baseline's."""
    worse: int
    """Objects where it is below."""

    @property
    def verdict(self) -> str:
        """``above`` / ``below`` when the whole interval is on one side of 0, else ``not distinguishable``;
        ``too few objects`` under :data:`MIN_OBJECTS`."""
        if self.objects < MIN_OBJECTS:
            return "too few objects"
        if self.low > 0:
            return "above"
        if self.high < 0:
            return "below"
        return "not distinguishable"

    def as_dict(self) -> dict:
        """The JSON row of ``ges compare-experts --out`` (split None written ``all``, the verdict included)."""
        return {"expert": self.expert, "split": self.split or "all", "objects": self.objects, "points": self.points,
                "low": self.low, "high": self.high, "better": self.better, "worse": self.worse,
                "verdict": self.verdict}  # fmt: skip


def _same_but_gained(a: dict, b: dict, name: str) -> bool:
    """Whether settings ``a`` and ``b`` of expert ``name`` differ only by settings the plugin gained since one of
    them was stored, at their defaults (:mod:`ges_core.experts.gained`)."""
    from ges_core.registry import load_registry

    registry = load_registry()
    return with_gained_settings(a, name, registry) == with_gained_settings(b, name, registry)


def pool_matrices(matrices: list[SuccessMatrix]) -> SuccessMatrix:
    """One matrix whose cells add the episodes and successes of ``matrices`` (runs of the same objects under other
    seeds), over the expert columns every matrix has (in the first one's order; see :func:`common_columns`).
    ConfigError naming what differs when the rows or splits differ, when a shared column ran other settings (another
    checkpoint under the same label is not more episodes of one expert) or when the baselines differ."""
    if not matrices:
        raise ConfigError("pool_matrices: no matrix given")
    first = matrices[0]
    for k, m in enumerate(matrices[1:], start=2):
        if m.object_ids != first.object_ids or m.splits != first.splits:
            extra = sorted(set(m.object_ids) - set(first.object_ids))
            missing = sorted(set(first.object_ids) - set(m.object_ids))
            raise ConfigError(
                f"matrix {k} holds other objects than matrix 1 (only in {k}: {extra[:5]}, only in 1: {missing[:5]}"
                f"{', or the same in another order or split' if not extra and not missing else ''}); pool runs of "
                "one dataset selection"
            )
        if m.baseline != first.baseline:
            raise ConfigError(f"matrix {k} has the baseline column {m.baseline}, matrix 1 {first.baseline}")
    labels = common_columns(matrices)
    if not labels:
        raise ConfigError(f"the matrices share no expert column: {[list(m.experts) for m in matrices]}")
    subsets = [select_columns(m, labels) for m in matrices]
    for k, m in enumerate(subsets[1:], start=2):
        for j, label in enumerate(labels):
            a, b = subsets[0].expert_settings[j], m.expert_settings[j]
            if a != b and not _same_but_gained(a, b, subsets[0].expert_names[j]):
                raise ConfigError(f"expert column '{label}' ran other settings in matrix {k} ({b}) than in 1 ({a})")
    return replace(
        subsets[0],
        episodes=sum(m.episodes for m in subsets),
        successes={p: sum(m.successes[p] for m in subsets) for p in PROTOCOLS},
    )


def column_list(text: str) -> list[str]:
    """``"a, b,c"`` -> ``["a", "b", "c"]`` (a ``--experts`` option's value)."""
    return [label.strip() for label in text.split(",") if label.strip()]


def select_columns(matrix: SuccessMatrix, labels: list[str] | tuple[str, ...]) -> SuccessMatrix:
    """``matrix`` with only the columns ``labels`` (in that order, duplicates dropped); ConfigError naming the
    matrix's columns for an unknown one. The baseline label stays set (``compare_to_baseline`` needs its column
    among ``labels``)."""
    labels = tuple(dict.fromkeys(labels))
    if unknown := [label for label in labels if label not in matrix.experts]:
        raise ConfigError(f"no expert column {', '.join(map(repr, unknown))} in the matrix; columns: "
                          f"{', '.join(matrix.experts)}")  # fmt: skip
    cols = [matrix.column(label) for label in labels]
    return replace(
        matrix,
        experts=labels,
        expert_names=tuple(matrix.expert_names[j] for j in cols),
        expert_settings=tuple(matrix.expert_settings[j] for j in cols),
        episodes=matrix.episodes[:, cols],
        successes={p: v[:, cols] for p, v in matrix.successes.items()},
    )


def common_columns(matrices: list[SuccessMatrix]) -> tuple[str, ...]:
    """Expert column labels every matrix has, in the first matrix's order."""
    shared = set.intersection(*(set(m.experts) for m in matrices)) if matrices else set()
    return tuple(label for label in (matrices[0].experts if matrices else ()) if label in shared)


def compare_to_baseline(
    matrix: SuccessMatrix,
    protocol: str = "paper",
    splits: tuple[str | None, ...] = (*SPLITS, None),
    resamples: int = 4000,
    level: float = 0.95,
    seed: int = 0,
) -> list[BaselineDifference]:
    """Every non-baseline column against the baseline column, per split (None: all objects); see the module docs.
    ConfigError when the matrix has no baseline column. Seeded: equal inputs give equal intervals."""
    if matrix.baseline is None or matrix.baseline not in matrix.experts:
        raise ConfigError("the matrix has no scripted-baseline column to compare with (ges eval-experts adds one)")
    if protocol not in PROTOCOLS:
        raise ConfigError(f"unknown success protocol '{protocol}'; choose one of {', '.join(PROTOCOLS)}")
    if not 0 < level < 1:
        raise ConfigError(f"level must be in (0, 1), got {level}")
    b = matrix.column(matrix.baseline)
    out = []
    for j, label in enumerate(matrix.experts):
        if j == b:
            continue
        for split in splits:
            rows = matrix.rows(split) & (matrix.episodes[:, j] > 0) & (matrix.episodes[:, b] > 0)
            out.append(_difference(matrix, protocol, label, j, b, split, rows, resamples, level, seed))
    return out


def _difference(matrix, protocol, label, j, b, split, rows, resamples, level, seed) -> BaselineDifference:
    n_e, n_b = matrix.episodes[rows, j], matrix.episodes[rows, b]
    k_e, k_b = matrix.successes[protocol][rows, j], matrix.successes[protocol][rows, b]
    n = int(rows.sum())
    if n == 0:
        nan = float("nan")
        return BaselineDifference(label, split, 0, nan, nan, nan, 0, 0)
    points = 100 * (k_e.sum() / n_e.sum() - k_b.sum() / n_b.sum())
    # (resamples, n) how often each object is drawn: the same draw for both columns (paired)
    draws = np.random.default_rng(seed).multinomial(n, np.full(n, 1 / n), size=resamples)
    diff = 100 * (draws @ k_e / (draws @ n_e) - draws @ k_b / (draws @ n_b))
    low, high = np.quantile(diff, [(1 - level) / 2, (1 + level) / 2])
    rate_e, rate_b = k_e / n_e, k_b / n_b
    return BaselineDifference(
        label, split, n, float(points), float(low), float(high),
        better=int((rate_e > rate_b).sum()), worse=int((rate_e < rate_b).sum()),
    )  # fmt: skip


def comparison_table(
    diffs: list[BaselineDifference],
    level: float = 0.95,
    *,
    title: str = "against the baseline",
    row_header: str = "expert",
    versus: dict[tuple[str, str | None], str] | None = None,
) -> str:
    """Markdown: one row per expert, one column per split: ``+1.2 [-0.4, +2.9] (5 up, 3 down)`` and the verdict
    marked (``above`` in bold). ``versus``: per (expert, split) the label of the column it was compared with, shown
    as ``vs LABEL`` (when the reference differs per split, as GES's best single expert does)."""
    splits = list(dict.fromkeys(d.split for d in diffs))
    experts = list(dict.fromkeys(d.expert for d in diffs))
    by = {(d.expert, d.split): d for d in diffs}
    lines = [
        f"{title}: points, {100 * level:.0f} % paired bootstrap interval over objects, objects up/down",
        "",
        f"| {row_header} | " + " | ".join(s or "all" for s in splits) + " |",
        "|---" * (len(splits) + 1) + "|",
    ]
    for e in experts:
        cells = []
        for s in splits:
            d = by[(e, s)]
            if d.objects == 0:
                cells.append("-")
                continue
            ref = f" vs {versus[(e, s)]}" if versus else ""
            text = f"{d.points:+.1f} [{d.low:+.1f}, {d.high:+.1f}]{ref} ({d.better} up, {d.worse} down)"
            cells.append(f"**{text} above**" if d.verdict == "above" else f"{text} {d.verdict}")
        lines.append(f"| {e} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class HeldOutOracle:
    """The oracle of one split picked on one run and scored on another (rates in [0, 1], over objects)."""

    split: str | None
    objects: int
    same: float
    """Oracle picked and scored on the picking run (the matrix's own oracle row)."""
    held_out: float
    """The picking run's choice per object, scored on the other run."""
    other: float
    """The other run's own oracle."""
    best_single: float
    """The best single column on the other run (mean over objects of its rate)."""
    best_label: str


def held_out_oracle(
    pick: SuccessMatrix, score: SuccessMatrix, protocol: str = "paper", splits: tuple[str | None, ...] = (*SPLITS, None)
) -> list[HeldOutOracle]:
    """Per split: each object's best column on ``pick`` (ties to the first column, as
    :meth:`SuccessMatrix.oracle`) scored on ``score``, beside both runs' own oracles and ``score``'s best single
    column. Objects with a cell missing in either run are left out. ConfigError when the runs hold other objects
    or share no column."""
    if pick.object_ids != score.object_ids:
        raise ConfigError("held_out_oracle: the two runs hold other objects; pool runs of one dataset selection")
    labels = common_columns([pick, score])
    if not labels:
        raise ConfigError(f"held_out_oracle: no common column ({list(pick.experts)} / {list(score.experts)})")
    rp, rs = (select_columns(m, labels).rates(protocol) for m in (pick, score))
    ok = ~np.isnan(rp).any(axis=1) & ~np.isnan(rs).any(axis=1)
    choice = np.where(ok, np.nan_to_num(rp, nan=-1.0).argmax(axis=1), 0)
    out = []
    for split in splits:
        rows = pick.rows(split) & ok
        n = int(rows.sum())
        if n == 0:
            out.append(HeldOutOracle(split, 0, *(float("nan"),) * 4, best_label="-"))
            continue
        per_column = rs[rows].mean(axis=0)
        out.append(HeldOutOracle(
            split, n, same=float(rp[rows].max(axis=1).mean()),
            held_out=float(rs[rows, choice[rows]].mean()), other=float(rs[rows].max(axis=1).mean()),
            best_single=float(per_column.max()), best_label=labels[int(per_column.argmax())],
        ))  # fmt: skip
    return out


def held_out_oracle_table(
    rows: list[HeldOutOracle], *, picked: str = "the first matrix", scored: str = "the others"
) -> str:
    """Markdown: per split, the oracle on the picking run's own episodes, its picks scored on the other run, the
    other run's own oracle and best single column. ``picked`` / ``scored`` name the two runs in the headers."""
    lines = [
        f"the oracle on fresh episodes: best column per object picked on {picked}, scored on {scored}",
        "",
        f"| split | objects | oracle of {picked} | picked on {picked}, scored on {scored} | oracle of {scored} "
        f"| best single column on {scored} |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.objects == 0:
            lines.append(f"| {r.split or 'all'} | 0 | - | - | - | - |")
            continue
        lines.append(
            f"| {r.split or 'all'} | {r.objects} | {100 * r.same:.1f} % | {100 * r.held_out:.1f} % | "
            f"{100 * r.other:.1f} % | {100 * r.best_single:.1f} % ({r.best_label}) |"
        )
    return "\n".join(lines)
