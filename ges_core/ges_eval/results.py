"""The results file of ``ges evaluate``: what each gate picked and the episodes GES ran, rewritten after every cell.

One JSON file, ``<out>/ges-<hand>-<sim>[-norand].json`` (format ``ges.ges_eval``, version 1; keys in
``docs/evaluate.md``): the run's settings (``run``, the same header as the success matrix), the matrix it
compares against, the experts GES chooses among (``experts``: column identities as in the matrix), the gates
(``gates``: checkpoint identity, picks and scores per object), the objects (split, category, grasp key) and one
cell per object and *chosen* expert (``cells[object][expert]``, the matrix's cell format, with ``source``: ``run``
when GES ran its episodes, ``matrix`` when ``--reuse-matrix`` took the matrix's cell of identical settings).

Cells are keyed by (object, expert), not by gate: two gates picking one expert for one object share the cell
(the same episodes under the same settings). The file is written atomically (:func:`ges_core.paths.atomic_write_text`)
after every cell, so a killed run loses at most the cell in progress and a rerun runs only what is missing.
"""

from __future__ import annotations

import json
from pathlib import Path

from ges_core.dataset.layout import utc_now
from ges_core.env.evaluate import grasp_key
from ges_core.errors import AssetError
from ges_core.experts.evaluate import check_stored_run, stored_columns
from ges_core.experts.matrix import PROTOCOLS
from ges_core.paths import atomic_write_text

__all__ = ["RESULTS_FORMAT", "RESULTS_VERSION", "ResultsFile", "read_results_json", "results_path"]

RESULTS_FORMAT = "ges.ges_eval"
RESULTS_VERSION = 1


def results_path(out: str | Path, hand: str, sim: str, randomized: bool = True) -> Path:
    """``<out>/ges-<hand>-<sim>.json`` (``-norand`` without randomization, as the matrix file is named)."""
    return Path(out) / f"ges-{hand}-{sim}{'' if randomized else '-norand'}.json"


def read_results_json(path: str | Path) -> dict:
    """The raw JSON of a results file, format and version checked (AssetError saying what to do otherwise)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"cannot read the GES results {path}: {exc}; delete it or choose another --out") from exc
    if not isinstance(data, dict) or data.get("format") != RESULTS_FORMAT or data.get("version") != RESULTS_VERSION:
        raise AssetError(
            f"{path} is not a GES results file (format {RESULTS_FORMAT!r}, version {RESULTS_VERSION}); "
            "choose another --out or delete it"
        )
    return data


class ResultsFile:
    """The results file being filled (module docs)."""

    def __init__(self, path: Path, data: dict) -> None:
        self.path, self.data = path, data

    @classmethod
    def open(
        cls, path: Path, header: dict, experts: dict[str, dict], dataset: Path, matrix: Path, registry
    ) -> ResultsFile:
        """The file at ``path`` (empty if none), checked: the stored run settings and every stored expert this run
        names must be this run's (ConfigError naming the differences otherwise; a setting an expert gained since
        the file was written counts at its default, :func:`~ges_core.experts.evaluate.stored_columns`)."""
        data = {"run": header, "dataset": str(dataset), "matrix": str(matrix), "experts": {}, "gates": {},
                "objects": {}, "cells": {}}  # fmt: skip
        if path.is_file():
            stored = read_results_json(path)
            stored["experts"] = stored_columns(stored.get("experts", {}), registry)
            check_stored_run(path, "GES results", stored, header, experts)
            data |= {k: stored[k] for k in ("experts", "gates", "objects", "cells") if k in stored}
        data["experts"] |= experts
        data["dataset"], data["matrix"] = str(dataset), str(matrix)
        return cls(path, data)

    def set_objects(self, records) -> None:
        """Entries for ``records``; an object whose grasp changed (another grasp key) loses its cells."""
        objects = dict(self.data["objects"])
        for r in records:
            key = grasp_key(r)
            if objects.get(r.object_id, {}).get("grasp_key") != key:
                self.data["cells"].pop(r.object_id, None)
            objects[r.object_id] = {"split": r.split, "category": r.category, "grasp_key": key}
        self.data["objects"] = objects

    def set_gate(self, label: str, identity: dict, picks) -> None:
        """Store gate ``label``: its checkpoint identity, and per object its pick and scores (a :class:`Picks`)."""
        self.data["gates"][label] = {**identity, "picks": picks.chosen, "scores": picks.scores}

    def cell(self, object_id: str, expert: str) -> dict | None:
        return self.data["cells"].get(object_id, {}).get(expert)

    def put(self, object_id: str, expert: str, cell: dict) -> None:
        """Store one cell and rewrite the file."""
        self.data["cells"].setdefault(object_id, {})[expert] = cell
        self.write()

    def write(self) -> None:
        head = {"format": RESULTS_FORMAT, "version": RESULTS_VERSION, "updated": utc_now(), "protocols": PROTOCOLS}
        atomic_write_text(self.path, json.dumps({**head, **self.data}, indent=1) + "\n", fix="choose another --out")
