"""Is GES above the best single expert, or only lucky? Each gate's GES episodes against the split's best expert.

Table 2 sets GES's success beside every expert's; with 4 episodes per object one episode moves a split's rate by
0.15-1.3 points, so "GES above the best single expert" is read as :mod:`ges_core.experts.compare` reads an expert
against the baseline: per split, GES minus the best single expert *of that split* (among the experts GES chooses
from, on the same objects and episodes' draws), with a paired bootstrap interval over objects and a verdict
(``above`` only when the whole interval is above 0).

Picking the best expert per split after seeing the split's rates favours it (the maximum of noisy columns), so
``above`` here is the harder test.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ges_core.experts.compare import BaselineDifference, compare_to_baseline, comparison_table, select_columns
from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix
from ges_core.ges_eval.table import COLUMNS, GesRow

__all__ = ["against_best_json", "ges_against_best", "ges_against_best_table", "ges_between"]


def ges_against_best(
    matrix: SuccessMatrix,
    rows: list[GesRow],
    experts: list[str] | tuple[str, ...],
    protocol: str = "paper",
    resamples: int = 4000,
    seed: int = 0,
) -> list[tuple[str, BaselineDifference]]:
    """Per split (and all objects) and gate: ``(best expert's label, GES (gate) minus it)``.

    matrix: the matrix view of the run (rows are the GES rows' objects); rows: each gate's GES episodes;
    experts: the columns GES chooses among (the best single expert is the one of them with the highest rate on
    the split's objects; ties to the first). Objects without GES episodes or without a cell of that expert are left
    out of that comparison."""
    view = select_columns(matrix, list(experts))
    ges_labels = tuple(f"GES ({r.label})" for r in rows)
    joined = _joined(view, rows)
    out = []
    for split in COLUMNS:
        sel = view.rows(split)
        wins = view.successes[protocol][sel].sum(axis=0)
        eps = view.episodes[sel].sum(axis=0)
        rates = np.where(eps > 0, wins / np.maximum(eps, 1), -1.0)
        best = view.experts[int(np.argmax(rates))]
        keep = [best, *ges_labels]
        against = replace(select_columns(joined, keep), baseline=best)
        for d in compare_to_baseline(against, protocol, splits=(split,), resamples=resamples, seed=seed):
            out.append((best, d))
    return out


def ges_between(
    matrix: SuccessMatrix,
    rows: list[GesRow],
    pairs: list[tuple[str, str]],
    protocol: str = "paper",
    resamples: int = 4000,
    seed: int = 0,
) -> list[tuple[str, BaselineDifference]]:
    """Per split (and all objects) and pair ``(a, b)`` of gate labels: ``(b's label, GES (a) minus GES (b))``, paired
    over the objects both have GES episodes on, as :func:`ges_against_best` (e.g. a distilled gate against the
    averaged one it imitates). A label no row holds is a KeyError naming the labels there are."""
    by_label = {r.label: r for r in rows}
    for label in {x for pair in pairs for x in pair}:
        if label not in by_label:
            raise KeyError(f"no GES row '{label}'; the rows are {sorted(by_label)}")
    joined = _joined(select_columns(matrix, []), rows)
    out = []
    for a, b in pairs:
        against = replace(select_columns(joined, [f"GES ({b})", f"GES ({a})"]), baseline=f"GES ({b})")
        for split in COLUMNS:
            for d in compare_to_baseline(against, protocol, splits=(split,), resamples=resamples, seed=seed):
                out.append((b, d))
    return out


def _joined(view: SuccessMatrix, rows: list[GesRow]) -> SuccessMatrix:
    """``view`` with one more column per GES row, ``GES (label)``, holding its episodes."""
    return replace(
        view,
        experts=(*view.experts, *(f"GES ({r.label})" for r in rows)),
        expert_names=(*view.expert_names, *("ges",) * len(rows)),
        expert_settings=(*view.expert_settings, *({"gate": r.label} for r in rows)),
        episodes=np.column_stack([view.episodes, *(r.episodes for r in rows)]),
        successes={p: np.column_stack([view.successes[p], *(r.successes[p] for r in rows)]) for p in PROTOCOLS},
    )


def ges_against_best_table(
    diffs: list[tuple[str, BaselineDifference]],
    level: float = 0.95,
    title: str = "GES against the best single expert of each split",
) -> str:
    """Markdown: one row per gate, one column per split: ``+1.2 [-0.4, +2.9] vs res1 (5 up, 3 down)`` and the
    verdict (:func:`ges_core.experts.compare.comparison_table`'s format); also for :func:`ges_between`'s pairs."""
    return comparison_table(
        [d for _, d in diffs], level, title=title, row_header="gate",
        versus={(d.expert, d.split): best for best, d in diffs},
    )  # fmt: skip


def against_best_json(diffs: list[tuple[str, BaselineDifference]]) -> list[dict]:
    """The comparisons as JSON rows: the best expert's label, every field of the difference and its verdict."""
    return [{"best_expert": best, **d.__dict__, "verdict": d.verdict} for best, d in diffs]
