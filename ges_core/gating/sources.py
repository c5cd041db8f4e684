"""Success rates from the matrix file ``ges eval-experts`` writes (:mod:`ges_core.experts.matrix`).

The gate code itself reads only :class:`~ges_core.gating.data.SuccessRates`; this module is the one
adapter from the file format.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ges_core.errors import ConfigError
from ges_core.gating.data import SuccessRates

__all__ = ["MatrixRates", "load_rates", "rates_from_matrix"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MatrixRates:
    """The rates of one matrix file, every split, with what the gate run needs to know about its rows."""

    rates: SuccessRates
    splits: tuple[str, ...]
    """Per row: train, unseen_object or unseen_category."""
    dataset: str
    """The Stage 1 dataset folder the matrix was evaluated on ('' if the file does not say)."""
    incomplete: tuple[str, ...]
    """Objects left out because a cell of theirs has no episodes yet (an evaluation still running)."""
    categories: tuple[str, ...]
    """Per row: the object's category (the matrix's)."""

    def split(self, name: str) -> SuccessRates:
        """The rows of split ``name``."""
        return self.rates.subset([i for i, s in enumerate(self.splits) if s == name])

    def split_categories(self, name: str) -> tuple[str, ...]:
        """The categories of the rows of split ``name`` (the order of :meth:`split`)."""
        return tuple(c for c, s in zip(self.categories, self.splits, strict=True) if s == name)


def rates_from_matrix(
    matrix, protocol: str = "paper", *, columns: list[str] | None = None
) -> tuple[SuccessRates, tuple[str, ...], tuple[str, ...]]:
    """(rates, splits per row, left-out ids) from a :class:`ges_core.experts.matrix.SuccessMatrix`.

    columns: the expert columns to keep, in this order (None: every column but the scripted baseline's,
    which the matrix carries for comparison; all if that leaves fewer than 2). Objects with an unevaluated
    cell among them are left out (and returned) rather than guessed.
    """
    labels = list(columns) if columns is not None else [c for c in matrix.experts if c != matrix.baseline]
    if columns is None and len(labels) < 2:
        labels = list(matrix.experts)
    unknown = [c for c in labels if c not in matrix.experts]
    if unknown:
        raise ConfigError(f"expert column(s) {unknown} not in the matrix; its columns: {list(matrix.experts)}")
    cols = [matrix.experts.index(c) for c in labels]
    all_rates = matrix.rates(protocol)[:, cols]
    done = ~np.isnan(all_rates).any(axis=1)
    left = tuple(o for o, ok in zip(matrix.object_ids, done, strict=True) if not ok)
    if left:
        log.warning("%d object(s) have unevaluated cells and are left out: %s", len(left), ", ".join(left[:5]))
    rows = np.flatnonzero(done)
    rates = SuccessRates(tuple(matrix.object_ids[i] for i in rows), tuple(labels), all_rates[rows])
    return rates, tuple(matrix.splits[i] for i in rows), left


def load_rates(
    path: str | Path, protocol: str = "paper", *, columns: list[str] | None = None, pool: Sequence[str | Path] = ()
) -> MatrixRates:
    """:class:`MatrixRates` of the matrix file at ``path``.

    pool: more matrix files of the same objects and expert columns (other evaluation seeds, ``ges eval-experts -o
    seed=1 -o env.randomization.seed=1``): their episodes and successes are added to the first's before the rates
    are taken, so each target rests on more episodes (``ges_core.experts.compare.pool_matrices``, which refuses
    other objects or a column run with other settings). Without ``columns`` the pooled columns are those every
    file has; a column missing from one of them is a ConfigError when ``columns`` names it.
    """
    from ges_core.experts.compare import pool_matrices, select_columns
    from ges_core.experts.matrix import matrix_from_json, read_matrix_json

    data = read_matrix_json(path)
    matrix = matrix_from_json(data)
    if pool:
        matrices = [matrix, *(matrix_from_json(read_matrix_json(p)) for p in pool)]
        if columns is not None:
            matrices = [select_columns(m, columns) for m in matrices]
        matrix = pool_matrices(matrices)
        log.info("pooled %d matrices: %.1f episodes per cell on average", len(matrices),
                 float(np.mean(matrix.episodes)))  # fmt: skip
    rates, splits, left = rates_from_matrix(matrix, protocol, columns=columns)
    category = dict(zip(matrix.object_ids, matrix.categories, strict=True))
    categories = tuple(category[o] for o in rates.object_ids)
    return MatrixRates(rates, splits, str(data.get("dataset") or ""), left, categories)
