"""What ``ges evaluate`` leaves beside its results file: Table 2 as JSON and markdown, and the expert-fusion PNG."""

from __future__ import annotations

import json
from pathlib import Path

from ges_core.dataset.layout import utc_now
from ges_core.ges_eval.against_best import against_best_json, ges_against_best_table
from ges_core.ges_eval.figure import fusion_figure
from ges_core.paths import atomic_write_text

__all__ = ["write_outputs"]


def write_outputs(report, run: dict) -> dict[str, Path]:
    """Write ``table2-*.json``, ``table2-*.md`` and ``fusion-*.png`` next to ``report.path`` (``ges-*.json``, the same
    hand/sim/randomization suffix); ``run``: the run's settings (stored in the JSON). Returns name -> path."""
    stem = report.path.stem.removeprefix("ges-")
    folder = report.path.parent
    paths = {"json": folder / f"table2-{stem}.json", "markdown": folder / f"table2-{stem}.md",
             "figure": folder / f"fusion-{stem}.png"}  # fmt: skip
    table = report.table
    payload = {"format": "ges.table2", "version": 1, "updated": utc_now(), "results": str(report.path),
               "matrix": str(report.matrix_path), "run": run, **table.to_json(),
               "picks": {label: p.chosen for label, p in report.picks.items()},
               "against_best": against_best_json(report.against_best)}  # fmt: skip
    atomic_write_text(paths["json"], json.dumps(payload, indent=1) + "\n", fix="choose another --out")
    parts = [*(table.markdown(p) for p in table.rows), table.accuracy_markdown("paper")]
    if report.against_best:
        parts.append(ges_against_best_table(report.against_best))
    text = "\n\n".join(parts)
    atomic_write_text(paths["markdown"], f"# Table 2: GES against every expert and the oracle\n\n{text}\n")
    fusion_figure(paths["figure"], report.matrix, table.experts, report.ges_rows)
    return paths
