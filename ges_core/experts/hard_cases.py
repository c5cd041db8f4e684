"""The hard-case set: training objects that even their two best experts rarely lift (the paper's hard-case expert).

The paper evaluates the experts on the training objects, takes each object's two best experts, and collects the
objects where both stay under a threshold; one more expert then trains on that set with curriculum stages 1-2.

>>> hard = find_hard_cases(load_matrix("runs/tiny/eval/matrix-allegro-sapien.json"), threshold=0.5)
>>> hard.object_ids                       # the set, in matrix row order
>>> hard.train_command("runs/tiny/dataset")

Both of the two best staying under the threshold is the same as the best one staying under it; the paper's
wording is kept (with its two cluster experts, "both" means every expert), and each object's two best are
reported as the evidence.

Which columns count: the learned experts, that is every column but the scripted baseline's (the paper's
experts are all learned; the baseline is a reference, not an expert the gate may pick). ``with_baseline=True``
counts it too. An object with fewer than two evaluated columns uses the ones it has.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ges_core.errors import ConfigError
from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix

__all__ = ["HardCases", "find_hard_cases"]

TOP = 2
"""How many best experts per object must all stay under the threshold (the paper's two)."""


@dataclass(frozen=True)
class HardCases:
    """The hard-case set of one matrix and the evidence for each object."""

    object_ids: tuple[str, ...]
    """The hard objects, in matrix row order."""
    best: dict[str, tuple[tuple[str, float], ...]]
    """Every object of the split considered -> its best experts (label, success rate), best first, at most TOP."""
    threshold: float
    """An object is hard when each of its TOP best rates is below this."""
    protocol: str
    """The success protocol the rates count (:data:`~ges_core.experts.matrix.PROTOCOLS`)."""
    experts: tuple[str, ...]
    """The columns that counted."""
    split: str
    """The rows considered (the paper: train)."""

    def train_command(self, dataset: str, name: str = "expert_hard", config: str | Path | None = None) -> str:
        """The ``ges train-expert`` line that trains the hard-case expert on this set (curriculum stages 1-2).

        ``config``: a cluster expert's resolved ``config.yaml`` (its run folder's), given as ``--config`` so the
        hard-case expert trains with the same hand, simulator, action mode, grasp selection, reward and budget;
        without it the line trains with the tiny preset's settings."""
        ids = "[" + ", ".join(self.object_ids) + "]"
        base = f"--config {shlex.quote(str(config))} " if config else ""
        return (
            f"ges train-expert {shlex.quote(str(dataset))} --name {name} {base}"
            f"-o {shlex.quote(f'objects={ids}')} -o {shlex.quote('curriculum.stages=[1, 2]')}"
        )

    def table(self) -> str:
        """One line per considered object: its best experts and rates, hard ones marked."""
        lines = [f"{'object':<36} {'hard':<5} best experts ({self.protocol} protocol)"]
        for oid, best in self.best.items():
            mark = "yes" if oid in self.object_ids else ""
            text = ", ".join(f"{label} {rate:.2f}" for label, rate in best) or "(no evaluated cell)"
            lines.append(f"{oid:<36} {mark:<5} {text}")
        return "\n".join(lines)


def find_hard_cases(
    matrix: SuccessMatrix,
    threshold: float = 0.5,
    *,
    protocol: str = "paper",
    split: str = "train",
    with_baseline: bool = False,
) -> HardCases:
    """The objects of ``split`` whose TOP best expert columns all have success rate < ``threshold``.

    ConfigError for a threshold outside (0, 1], an unknown protocol, a split without rows or a matrix without a
    column to count. Rows with no evaluated cell among the counted columns are left out (not hard: not known).
    """
    if not 0.0 < threshold <= 1.0:
        raise ConfigError(f"hard-case threshold {threshold} must lie in (0, 1] (a success rate)")
    if protocol not in PROTOCOLS:
        raise ConfigError(f"unknown success protocol '{protocol}'; choose one of {', '.join(PROTOCOLS)}")
    cols = [j for j, label in enumerate(matrix.experts) if with_baseline or label != matrix.baseline]
    if not cols:
        raise ConfigError(
            f"the matrix has no expert column to count besides the baseline ({', '.join(matrix.experts)}); "
            "evaluate learned experts with ges eval-experts --expert ..., or pass --with-baseline"
        )
    rows = np.flatnonzero(matrix.rows(split))
    if rows.size == 0:
        raise ConfigError(f"the matrix has no '{split}' object; its splits: {', '.join(sorted(set(matrix.splits)))}")
    rates = matrix.rates(protocol)[:, cols]
    labels = [matrix.experts[j] for j in cols]
    best: dict[str, tuple[tuple[str, float], ...]] = {}
    hard: list[str] = []
    for i in rows:
        seen = [(labels[k], float(rates[i, k])) for k in range(len(cols)) if not np.isnan(rates[i, k])]
        top = tuple(sorted(seen, key=lambda item: -item[1])[:TOP])  # sorted() is stable: ties keep column order
        best[matrix.object_ids[i]] = top
        if top and all(rate < threshold for _, rate in top):
            hard.append(matrix.object_ids[i])
    return HardCases(tuple(hard), best, threshold, protocol, tuple(labels), split)
