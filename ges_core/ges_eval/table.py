"""The project's Table 2: every expert alone, the scripted baseline, the oracle and GES with each gate, per split.

Rows and what each cell counts (per split: train, unseen_object, unseen_category, and all):

* **an expert alone** / **the scripted baseline**: its successful episodes over every episode of the split's
  objects, from the success matrix (``ges eval-experts``);
* **oracle**: the mean over the split's objects of each object's best success rate among the experts GES chooses
  from (a perfect gate); objects with an unevaluated cell are left out;
* **GES (gate)**: the episodes GES ran, each object with the expert the gate picked (the results file), and the
  share of objects whose pick is one of their best experts in the matrix (the paper's gate accuracy).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix
from ges_core.gating.data import best_experts
from ges_core.objects.splits import SPLITS

__all__ = ["COLUMNS", "GesRow", "Table2", "table2"]

COLUMNS: tuple[str | None, ...] = (*SPLITS, None)
"""Table columns: the three splits, then every object (None, shown as ``all``)."""


@dataclass(frozen=True)
class GesRow:
    """One gate's GES episodes per object (row order of the matrix view): successes per protocol and episodes."""

    label: str
    successes: dict[str, np.ndarray]
    """Protocol -> (n_objects,) int64 successful episodes of the picked expert."""
    episodes: np.ndarray
    """(n_objects,) int64 episodes GES ran (0: not run yet)."""
    picked: np.ndarray
    """(n_objects,) int64 column of the matrix view the gate picked."""


@dataclass
class Table2:
    """Table 2 as data: per protocol, rows of ``{"row", "kind", "splits": {split: cell}}`` (module docs)."""

    rows: dict[str, list[dict]] = field(default_factory=dict)
    experts: tuple[str, ...] = ()

    def markdown(self, protocol: str = "paper") -> str:
        """Markdown table of ``protocol``: one row per entry, one column per split and ``all``."""
        head = [
            f"success ({protocol}: {PROTOCOLS[protocol]})",
            "",
            "| | " + " | ".join(s or "all" for s in COLUMNS) + " |",
            "|---" * (len(COLUMNS) + 1) + "|",
        ]
        lines = [f"| {r['row']} | " + " | ".join(_text(r["splits"][s or "all"]) for s in COLUMNS) + " |"
                 for r in self.rows[protocol]]  # fmt: skip
        return "\n".join(head + lines)

    def accuracy_markdown(self, protocol: str = "paper") -> str:
        """Markdown: per gate and split, the share of objects whose pick is one of their best experts (objects
        where every expert failed left out, as ``ges train-gate`` counts)."""
        lines = ["| gate: pick among the best | " + " | ".join(s or "all" for s in COLUMNS) + " |",
                 "|---" * (len(COLUMNS) + 1) + "|"]  # fmt: skip
        for r in self.rows[protocol]:
            if r["kind"] == "ges":
                cells = [r["splits"][s or "all"]["pick_best"] for s in COLUMNS]
                lines.append(f"| {r['gate']} | " + " | ".join("-" if c is None else f"{100 * c:.1f} %" for c in cells)
                             + " |")  # fmt: skip
        return "\n".join(lines)

    def to_json(self) -> dict:
        return {"experts": list(self.experts), "protocols": PROTOCOLS, "rows": self.rows}

    def rate(self, protocol: str, row: str, split: str = "all") -> float | None:
        """The rate of the row named ``row`` (KeyError listing the rows)."""
        for r in self.rows[protocol]:
            if r["row"] == row:
                return r["splits"][split]["rate"]
        raise KeyError(f"no row '{row}'; rows: {[r['row'] for r in self.rows[protocol]]}")


def table2(matrix: SuccessMatrix, experts: tuple[str, ...], ges: list[GesRow]) -> Table2:
    """Table 2 of a matrix view (rows: the run's objects; columns: the baseline and ``experts``, the labels GES
    chooses among) and the GES rows of each gate."""
    table = Table2(experts=experts)
    cols = [matrix.column(e) for e in experts]
    for p in PROTOCOLS:
        rows = [_expert_row(matrix, p, matrix.column(e), e, "expert") for e in experts]
        if matrix.baseline is not None and matrix.baseline not in experts:
            rows.append(_expert_row(matrix, p, matrix.column(matrix.baseline), f"{matrix.baseline} (baseline)",
                                    "baseline"))  # fmt: skip
        rows.append(_oracle_row(matrix, p, cols, experts))
        rows += [_ges_row(matrix, p, cols, g) for g in ges]
        table.rows[p] = rows
    return table


def _count(k: int, n: int, objects: int) -> dict:
    return {"rate": (k / n) if n else None, "successes": k, "episodes": n, "objects": objects}


def _expert_row(matrix: SuccessMatrix, protocol: str, col: int, name: str, kind: str) -> dict:
    splits = {}
    for s in COLUMNS:
        rows = matrix.rows(s)
        k, n = int(matrix.successes[protocol][rows, col].sum()), int(matrix.episodes[rows, col].sum())
        splits[s or "all"] = _count(k, n, int(rows.sum()))
    return {"row": name, "kind": kind, "splits": splits}


def _oracle_row(matrix: SuccessMatrix, protocol: str, cols: list[int], experts: tuple[str, ...]) -> dict:
    rates = matrix.rates(protocol)[:, cols]
    done = ~np.isnan(rates).any(axis=1)
    best = np.where(done, np.nan_to_num(rates).max(axis=1), np.nan)
    splits = {}
    for s in COLUMNS:
        b = best[matrix.rows(s) & done]
        splits[s or "all"] = {"rate": float(b.mean()) if b.size else None, "objects": int(b.size)}
    return {"row": f"oracle (best of {', '.join(experts)} per object)", "kind": "oracle", "splits": splits}


def _ges_row(matrix: SuccessMatrix, protocol: str, cols: list[int], g: GesRow) -> dict:
    rates = matrix.rates(protocol)[:, cols]
    done = ~np.isnan(rates).any(axis=1)
    local = np.array([cols.index(c) for c in g.picked], dtype=np.int64)
    good = np.zeros(len(local), dtype=bool)
    if done.any():
        good[done] = best_experts(rates[done])[np.arange(int(done.sum())), local[done]]
    splits = {}
    for s in COLUMNS:
        rows = matrix.rows(s)
        k, n = int(g.successes[protocol][rows].sum()), int(g.episodes[rows].sum())
        cell = _count(k, n, int(rows.sum()))
        scored = rows & done & (rates.max(axis=1, initial=0.0, where=~np.isnan(rates)) > 0)
        cell["pick_best"] = float(good[scored].mean()) if scored.any() else None
        splits[s or "all"] = cell
    return {"row": f"GES ({g.label})", "kind": "ges", "gate": g.label, "splits": splits}


def _text(cell: dict) -> str:
    if cell["rate"] is None:
        return "-"
    if "episodes" not in cell:
        return f"{100 * cell['rate']:.1f} % ({cell['objects']} obj)"
    return f"{100 * cell['rate']:.1f} % ({cell['successes']}/{cell['episodes']})"
