"""The expert rows of the paper's Table 2 from a success matrix: success per expert and split, baseline, oracle."""

from __future__ import annotations

import numpy as np

from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix
from ges_core.objects.splits import SPLITS

__all__ = ["LATE_SHARE", "expert_table", "late_columns", "split_rates"]

LATE_SHARE = 0.05
"""Share of a column's episodes ending ``timeout`` (lifted, not yet held, out of control steps) from which
:func:`late_columns` names it. Measured on the procedural library (265 objects, 4 episodes): the scripted expert and
the PPO experts 0.4-0.5 %; the script with a 15-step pause 28 % (300 of 1,060), 299 of them with the object 0.2 m up."""

OVERSHOOT = 1.5
"""A late column whose late episodes' median highest rise is above this many lift heights does not run out of steps
while holding: the object was thrown or swung (an untrained PPO expert on the demo set sent a box 0.43 m up against
the 0.2 m lift), and :func:`late_columns` says so instead of suggesting a longer episode."""


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


def late_columns(
    cells: dict,
    matrix: SuccessMatrix,
    episode_length: int,
    share: float = LATE_SHARE,
    lift_height: float | None = None,
) -> list[str]:
    """One line per expert column of ``matrix`` whose episodes ran out of control steps with the object lifted (end
    reason ``timeout``) in at least ``share`` of its episodes on ``matrix``'s objects: its plan may not fit
    ``episode_length`` steps, which the paper protocol's hold needs at the end. ``cells``: the matrix file's cells
    (``read_matrix_json(path)["cells"]``, where each episode's end reason and highest rise are kept). With
    ``lift_height`` (m), a column whose late episodes went a median of more than :data:`OVERSHOOT` lift heights up is
    named as throwing or swinging the object instead (a longer episode would not help). Empty when no column is late."""
    lines = []
    for label in matrix.experts:
        reasons, rises = [], []
        for oid in matrix.object_ids:
            cell = cells.get(oid, {}).get(label, {})
            reasons += cell.get("end_reasons", ())
            pairs = zip(cell.get("end_reasons", ()), cell.get("max_rise", ()), strict=False)  # old cells: no rises
            rises += [h for r, h in pairs if r == "timeout"]
        n, late = len(reasons), reasons.count("timeout")
        if not (n and late / n >= share):
            continue
        head = f"expert '{label}': {late} of {n} episodes ({100 * late / n:.0f} %) ran out of the episode's "
        rise = float(np.median(rises)) if rises else None
        if lift_height is not None and rise is not None and rise > OVERSHOOT * lift_height:
            lines.append(
                head + f"{episode_length} control steps with the object lifted but not held, after going a median "
                f"{rise:.2f} m up against the {lift_height:g} m lift: it throws or swings the object rather than "
                "holding it (a longer episode will not help; train the expert further)"
            )
        else:
            lines.append(
                head + f"{episode_length} control steps with the object lifted but not yet held: its plan may not "
                "fit the episode (a longer one for every column: -o env.episode_length=N, into another --out)"
            )
    return lines
