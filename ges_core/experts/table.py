"""The expert rows of the paper's Table 2 from a success matrix: success per expert and split, baseline, oracle."""

from __future__ import annotations

import numpy as np

from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix
from ges_core.objects.splits import SPLITS

__all__ = ["expert_table", "split_rates"]


def split_rates(matrix: SuccessMatrix, protocol: str = "paper", split: str | None = None) -> dict[str, float | None]:
    """Column label -> success rate over every episode of the objects of ``split`` (all for None); None: no episodes.
    The oracle, under the key ``"oracle"``, is the mean over those objects of each one's best expert rate."""
    rows = matrix.rows(split)
    episodes = matrix.episodes[rows].sum(axis=0)
    wins = matrix.successes[protocol][rows].sum(axis=0)
    out = {label: (float(wins[j] / episodes[j]) if episodes[j] else None) for j, label in enumerate(matrix.experts)}
    best = matrix.oracle(protocol)[0][rows]
    best = best[~np.isnan(best)]
    out["oracle"] = float(best.mean()) if best.size else None
    return out


def expert_table(matrix: SuccessMatrix, protocol: str = "paper", splits: tuple[str, ...] = SPLITS) -> str:
    """Markdown: one row per expert column (the baseline marked), then the oracle (best expert per object);
    one column per split and ``all``; each cell ``rate (successes/episodes)``, the oracle's ``rate (objects)``."""
    if protocol not in PROTOCOLS:
        raise KeyError(f"unknown success protocol '{protocol}'; choose one of {', '.join(PROTOCOLS)}")
    parts = [*splits, None]
    rates = {s: split_rates(matrix, protocol, s) for s in parts}
    lines = [
        f"success ({protocol}: {PROTOCOLS[protocol]})",
        "",
        "| expert | " + " | ".join(s or "all" for s in parts) + " |",
        "|---" * (len(parts) + 1) + "|",
    ]
    for j, label in enumerate(matrix.experts):
        name = f"{label} (baseline)" if label == matrix.baseline else label
        cells = [_cell(matrix, protocol, s, j) for s in parts]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    oracle = []
    for s in parts:
        n = int((~np.isnan(matrix.oracle(protocol)[0][matrix.rows(s)])).sum())
        oracle.append(f"{100 * rates[s]['oracle']:.1f} % ({n} obj)" if rates[s]["oracle"] is not None else "-")
    lines.append("| oracle (best expert per object) | " + " | ".join(oracle) + " |")
    return "\n".join(lines)


def _cell(matrix: SuccessMatrix, protocol: str, split: str | None, column: int) -> str:
    rows = matrix.rows(split)
    n = int(matrix.episodes[rows, column].sum())
    k = int(matrix.successes[protocol][rows, column].sum())
    return f"{100 * k / n:.1f} % ({k}/{n})" if n else "-"
