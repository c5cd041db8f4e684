"""The objects x experts success matrix that ``ges eval-experts`` writes, and its reader.

>>> m = load_matrix("runs/demo/experts/matrix-allegro-sapien.json")
>>> m.object_ids, m.experts                 # rows, columns
>>> m.rates("paper")                        # (n_objects, n_experts) float64 success rates, NaN: not evaluated
>>> best, which = m.oracle("paper")         # (n_objects,) best rate per object and the column giving it

One JSON file, ``<out>/matrix-<hand>-<sim>[-norand].json`` (format ``ges.expert_matrix``, version 1; every key in
``docs/experts.md``): the run's settings (``run``), one entry per expert column (``experts``: registry name and
the full settings it ran with), one per object (``objects``: split, category, cluster, the key of its grasp) and
one cell per object and expert (``cells[object][expert]``: episodes, successes under both protocols, end reasons,
highest rise, steps). :func:`write_matrix` rewrites it atomically; the evaluation
(:mod:`ges_core.experts.evaluate`) does after every cell, so a killed run resumes where it stopped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ges_core.dataset.layout import utc_now
from ges_core.errors import AssetError
from ges_core.paths import atomic_write_text

__all__ = [
    "MATRIX_FORMAT",
    "MATRIX_VERSION",
    "PROTOCOLS",
    "SuccessMatrix",
    "load_matrix",
    "matrix_from_json",
    "matrix_path",
    "read_matrix_json",
    "write_matrix",
]

MATRIX_FORMAT = "ges.expert_matrix"
MATRIX_VERSION = 1
PROTOCOLS: dict[str, str] = {
    "paper": "object 0.2 m above its start and held there for 200 simulation steps (the paper's)",
    "peers": "object within 5 cm of the lift target at some step (UniDexGrasp's and its successors')",
}
"""Success protocols: the key of a cell's success count -> what it counts (``docs/env.md``)."""


def matrix_path(out: str | Path, hand: str, sim: str, randomized: bool = True) -> Path:
    """``<out>/matrix-<hand>-<sim>.json``; ``matrix-<hand>-<sim>-norand.json`` for a run without randomization (so
    the two runs of one hand and simulator sit side by side)."""
    return Path(out) / f"matrix-{hand}-{sim}{'' if randomized else '-norand'}.json"


@dataclass(frozen=True)
class SuccessMatrix:
    """A success matrix in memory: objects (rows) x experts (columns), per success protocol."""

    object_ids: tuple[str, ...]
    """Row order: the dataset's record order (objects of earlier runs that this one did not select after them)."""
    splits: tuple[str, ...]
    """Per row: train, unseen_object or unseen_category."""
    categories: tuple[str, ...]
    """Per row: the object's category."""
    clusters: tuple[int | None, ...]
    """Per row: the geometry cluster from the run's clusters file (``ges cluster``); None without one."""
    experts: tuple[str, ...]
    """Column labels (``--expert LABEL=NAME:...``; by default the NAME:settings text)."""
    expert_names: tuple[str, ...]
    """Per column: the expert's registry name."""
    expert_settings: tuple[dict[str, Any], ...]
    """Per column: every setting the expert ran with (plugin defaults, registry.yaml, the column's own)."""
    episodes: np.ndarray
    """(n_objects, n_experts) int64 episodes run; 0 where the cell is not evaluated (yet)."""
    successes: dict[str, np.ndarray]
    """Protocol (:data:`PROTOCOLS`) -> (n_objects, n_experts) int64 successful episodes."""
    baseline: str | None = None
    """Label of the scripted baseline's column, if the run had one."""

    def rates(self, protocol: str = "paper") -> np.ndarray:
        """(n_objects, n_experts) float64 success rates in [0, 1]; NaN where a cell has no episodes."""
        wins = self._successes(protocol).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.episodes > 0, wins / np.maximum(self.episodes, 1), np.nan)

    def oracle(self, protocol: str = "paper") -> tuple[np.ndarray, np.ndarray]:
        """Best expert per object: (n_objects,) float64 its rate (NaN: no cell evaluated) and (n_objects,) int64 its
        column (-1: none; ties go to the first column)."""
        rates = self.rates(protocol)
        n = rates.shape[0]
        if rates.shape[1] == 0:
            return np.full(n, np.nan), np.full(n, -1, dtype=np.int64)
        filled = np.nan_to_num(rates, nan=-1.0)
        best = filled.argmax(axis=1)
        has = ~np.isnan(rates).all(axis=1)
        return np.where(has, filled[np.arange(n), best], np.nan), np.where(has, best, -1).astype(np.int64)

    def rows(self, split: str | None = None) -> np.ndarray:
        """(n_objects,) bool: the rows of ``split`` (every row for None)."""
        return np.array([split is None or s == split for s in self.splits], dtype=bool)

    def column(self, label: str) -> int:
        """Index of the expert column ``label``; KeyError listing the columns."""
        if label not in self.experts:
            raise KeyError(f"no expert column '{label}' in the matrix; columns: {', '.join(self.experts)}")
        return self.experts.index(label)

    @property
    def complete(self) -> bool:
        """Every cell has episodes."""
        return bool((self.episodes > 0).all())

    def _successes(self, protocol: str) -> np.ndarray:
        if protocol not in self.successes:
            raise KeyError(f"unknown success protocol '{protocol}'; choose one of {', '.join(PROTOCOLS)}")
        return self.successes[protocol]


def read_matrix_json(path: str | Path) -> dict:
    """The raw JSON of a matrix file, its format and version checked (AssetError saying what to do otherwise)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"cannot read the success matrix {path}: {exc}; rerun ges eval-experts to write it") from exc
    if not isinstance(data, dict) or data.get("format") != MATRIX_FORMAT:
        raise AssetError(f"{path} is not a success matrix (format {MATRIX_FORMAT!r}); choose another file or --out")
    if data.get("version") != MATRIX_VERSION:
        raise AssetError(
            f"{path} holds a success matrix of version {data.get('version')!r}, this code reads {MATRIX_VERSION}; "
            "rerun ges eval-experts into another --out"
        )
    return data


def load_matrix(path: str | Path) -> SuccessMatrix:
    """Read the matrix file at ``path`` (:func:`matrix_path`)."""
    return matrix_from_json(read_matrix_json(path))


def matrix_from_json(data: dict) -> SuccessMatrix:
    """:class:`SuccessMatrix` of a matrix file's JSON (every object and expert column of the file)."""
    objects, experts, cells = data.get("objects", {}), data.get("experts", {}), data.get("cells", {})
    oids, labels = tuple(objects), tuple(experts)
    episodes = np.zeros((len(oids), len(labels)), dtype=np.int64)
    wins = {p: np.zeros_like(episodes) for p in PROTOCOLS}
    for i, oid in enumerate(oids):
        for j, label in enumerate(labels):
            cell = cells.get(oid, {}).get(label)
            if cell is not None:
                episodes[i, j] = cell["episodes"]
                for p in PROTOCOLS:
                    wins[p][i, j] = cell[p]
    return SuccessMatrix(
        object_ids=oids,
        splits=tuple(objects[o]["split"] for o in oids),
        categories=tuple(objects[o]["category"] for o in oids),
        clusters=tuple(objects[o].get("cluster") for o in oids),
        experts=labels,
        expert_names=tuple(experts[e]["name"] for e in labels),
        expert_settings=tuple(dict(experts[e]["settings"]) for e in labels),
        episodes=episodes,
        successes=wins,
        baseline=data.get("baseline"),
    )


def write_matrix(path: Path, data: dict) -> None:
    """Write the matrix JSON ``data`` (``run``, ``experts``, ``objects``, ``cells``, ...) atomically, stamped
    with the format, version and time."""
    out = {"format": MATRIX_FORMAT, "version": MATRIX_VERSION, "updated": utc_now(), "protocols": PROTOCOLS}
    atomic_write_text(path, json.dumps({**out, **data}, indent=1) + "\n")
