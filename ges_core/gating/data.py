"""What a gate learns from: per-object expert success rates, the targets made of them, and splits.

:class:`SuccessRates` is the in-memory success matrix (objects x experts), independent of the file
that ``ges eval-experts`` writes (:mod:`ges_core.gating.sources` reads that file into it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ges_core.errors import ArrayError, ConfigError

__all__ = [
    "ALL_FAILED",
    "SuccessRates",
    "best_experts",
    "category_smoothed",
    "fold_indices",
    "normalized",
    "split_indices",
    "targets",
]

ALL_FAILED = ("drop", "uniform")
"""What :func:`targets` does with an object whose every expert failed (see its docstring)."""

BEST_TOLERANCE = 1e-6
"""Success rates within this of an object's best count as best too (ties: 0.5 vs 0.5 from 2 of 4 trials)."""


@dataclass(frozen=True)
class SuccessRates:
    """Per-object success rate of each expert.

    object_ids: (n_objects,) unique ids; experts: (n_experts,) unique expert names, the column order;
    rates: (n_objects, n_experts) float64 in [0, 1], fraction of an object's trials that the expert won.
    """

    object_ids: tuple[str, ...]
    experts: tuple[str, ...]
    rates: np.ndarray

    def __post_init__(self) -> None:
        rates = np.asarray(self.rates, dtype=np.float64)
        object.__setattr__(self, "object_ids", tuple(self.object_ids))
        object.__setattr__(self, "experts", tuple(self.experts))
        object.__setattr__(self, "rates", rates)
        shape = (len(self.object_ids), len(self.experts))
        if rates.shape != shape:
            raise ArrayError(f"success rates have shape {rates.shape}, expected (objects, experts) = {shape}")
        for what, names in (("object id", self.object_ids), ("expert", self.experts)):
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ConfigError(f"success rates: {what}s repeated: {dup}; each must appear once")
        if len(self.experts) < 2:
            raise ConfigError(f"a gate chooses among at least 2 experts; the success rates have {list(self.experts)}")
        bad = ~np.isfinite(rates) | (rates < 0) | (rates > 1)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ArrayError(
                f"success rate of expert '{self.experts[j]}' on object '{self.object_ids[i]}' is {rates[i, j]}; "
                f"rates must be fractions in [0, 1] ({int(bad.sum())} bad entries)"
            )

    def subset(self, indices: Sequence[int] | np.ndarray) -> SuccessRates:
        """The rows ``indices``, in that order."""
        idx = np.asarray(indices, dtype=np.int64)
        return SuccessRates(tuple(self.object_ids[i] for i in idx), self.experts, self.rates[idx])

    def all_failed(self) -> np.ndarray:
        """(n_objects,) bool: no expert succeeded on the object even once."""
        return self.rates.max(axis=1) <= 0.0


def targets(rates: SuccessRates, all_failed: Literal["drop", "uniform"] = "drop") -> tuple[np.ndarray, np.ndarray]:
    """The gate's training targets P_i: each object's success rates normalized to sum to one.

    Returns (kept (m,) int64 row indices of ``rates``, P (m, n_experts) float64, rows sum to 1).
    ``all_failed``: "drop" leaves out the objects where every expert failed (the default: their target
    carries no preference, and pulling the gate towards uniform there blurs the shapes nearby whose
    best expert is known); "uniform" keeps them with P_i = 1/k.
    """
    if all_failed not in ALL_FAILED:
        raise ConfigError(f"all_failed must be one of {ALL_FAILED}, got {all_failed!r}")
    failed = rates.all_failed()
    kept = np.flatnonzero(~failed) if all_failed == "drop" else np.arange(len(rates.object_ids))
    return kept.astype(np.int64), normalized(rates.rates[kept])


def normalized(rates: np.ndarray) -> np.ndarray:
    """(m, k) each row of ``rates`` divided by its sum; a row summing to 0 becomes uniform, 1/k."""
    rates = np.asarray(rates, dtype=np.float64)
    total = rates.sum(axis=1, keepdims=True)
    return np.where(total > 0, rates / np.where(total > 0, total, 1.0), 1.0 / rates.shape[1])


def category_smoothed(rates: np.ndarray, categories: Sequence[str], rows: np.ndarray, weight: float) -> np.ndarray:
    """(len(rows), k) the rates of ``rows`` mixed with their category's: ``(1 - weight) * own + weight * mean``, the
    mean over the ``rows`` of the same category (so a category's mean never reads a row outside ``rows``: the
    validation objects stay out of the training targets).

    rates: (n, k) success rates; categories: (n,) category per row; rows: (m,) int row indices; weight in [0, 1].
    Why: an object's rates rest on a few episodes each (8 in the shipped studies: one episode moves a rate by
    0.125), and the gate's KL loss fits that noise; objects of one category mostly share their best expert.
    """
    rates = np.asarray(rates, dtype=np.float64)
    rows = np.asarray(rows, dtype=np.int64)
    if not 0.0 <= weight <= 1.0:
        raise ConfigError(f"category smoothing weight must be in [0, 1], got {weight}")
    if len(categories) != len(rates):
        raise ArrayError(f"{len(categories)} categories for {len(rates)} rows of success rates")
    labels = np.asarray([categories[i] for i in rows], dtype=object)
    out = rates[rows].copy()
    for label in set(labels.tolist()):
        same = labels == label
        out[same] = (1.0 - weight) * rates[rows[same]] + weight * rates[rows[same]].mean(axis=0)
    return out


def best_experts(rates: np.ndarray) -> np.ndarray:
    """(n, k) bool: the experts whose success rate is the object's best (within :data:`BEST_TOLERANCE`)."""
    rates = np.asarray(rates, dtype=np.float64)
    return rates >= rates.max(axis=1, keepdims=True) - BEST_TOLERANCE


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded (train, validation) split of range(n): sorted int64 index arrays, validation of
    round(n * val_fraction) objects (at least 1 when val_fraction > 0 and n >= 2), train never empty."""
    if not 0.0 <= val_fraction < 1.0:
        raise ConfigError(f"val_fraction must be in [0, 1), got {val_fraction}")
    n_val = round(n * val_fraction)
    if val_fraction > 0 and n >= 2:
        n_val = min(max(n_val, 1), n - 1)
    order = np.random.default_rng(seed).permutation(n)
    return np.sort(order[n_val:]).astype(np.int64), np.sort(order[:n_val]).astype(np.int64)


def fold_indices(n: int, folds: int, fold: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fold ``fold`` of a seeded ``folds``-way partition of range(n), as (train, validation): sorted int64 index
    arrays, the validation part one of ``folds`` near-equal parts (sizes differ by at most one), train the rest.

    The ``folds`` validation parts of one (n, folds, seed) are disjoint and cover range(n): every object is held out
    by exactly one fold (what ``train.folds`` needs for out-of-fold scores)."""
    if folds < 2:
        raise ConfigError(f"a fold split needs 2+ folds, got {folds}")
    if not 0 <= fold < folds:
        raise ConfigError(f"fold {fold} of {folds}: must be in [0, {folds - 1}]")
    if n < folds:
        raise ConfigError(f"{folds} folds of {n} object(s): each fold needs an object; give fewer folds")
    part = np.array_split(np.random.default_rng(seed).permutation(n), folds)[fold]
    return np.setdiff1d(np.arange(n), part).astype(np.int64), np.sort(part).astype(np.int64)
