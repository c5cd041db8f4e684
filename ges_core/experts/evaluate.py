"""``ges eval-experts``: every expert on every selected object, written as an objects x experts success matrix.

>>> config = BaselineConfig(hand="allegro", sim="sapien", envs=4, selection="validated")
>>> report = evaluate_experts("runs/demo/dataset", config, [parse_expert("slow=scripted:close_steps=60")], "out")
>>> print(report.table("paper"))

Each cell (object, expert) is one call of :func:`ges_core.env.evaluate.evaluate_object`, the episode runner of
``ges env baseline``: a fresh simulator for the object, ``config.envs`` episodes (E) of the expert built for that
env by the registry. The scripted baseline (column ``scripted``, its registered settings) is added unless one of
the given experts is labelled ``scripted``. Cells run object by object (every expert on one object, then the
next) and the matrix file (:mod:`~ges_core.experts.matrix`) is rewritten atomically after each, so a killed run
loses at most the cell in progress and a rerun evaluates only what is missing:

* the run's settings (``config`` but the record choice and the expert) must be those stored (ConfigError listing
  the differences otherwise);
* a stored column whose expert name or settings differ from the one given under its label is refused
  (ConfigError: give it another label);
* an object whose grasp changed (another ``grasp_key``) loses its stored cells and is evaluated again;
* columns and objects a rerun does not name stay in the file (its table shows the run's own).
"""

from __future__ import annotations

import functools
import hashlib
import json
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from ges_core.config import parse_model, stored_dump
from ges_core.dataset.layout import config_differences
from ges_core.env.evaluate import BaselineConfig, config_records, grasp_key
from ges_core.env.evaluate.fanout import Cell, Fanout, evaluate_cells
from ges_core.env.grasp_source import open_grasp_dataset
from ges_core.errors import AssetError, ConfigError
from ges_core.experts.choice import ExpertChoice
from ges_core.experts.gained import with_gained_settings
from ges_core.experts.matrix import SuccessMatrix, matrix_from_json, matrix_path, read_matrix_json, write_matrix
from ges_core.experts.table import expert_table, late_columns
from ges_core.paths import file_sha256

__all__ = [
    "BASELINE",
    "RANDOMIZED",
    "EvalReport",
    "cell_config",
    "cells_by_other_code",
    "check_stored_run",
    "code_stamp",
    "column_identity",
    "evaluate_experts",
    "is_randomized",
    "matrix_cell",
    "read_clusters",
    "run_header",
    "stored_columns",
]

BASELINE = ExpertChoice("scripted", "scripted", {})
"""The scripted baseline column: the ``scripted`` expert with its registered settings."""

RANDOMIZED: dict[str, bool] = {"start_pose": True, "mass": True, "friction": True, "obs_noise": True}
"""``env.randomization`` switches ``ges eval-experts`` turns on unless ``--no-randomization`` (amounts: the
:class:`~ges_core.env.randomization.RandomizationConfig` defaults; seeded, so every expert of one object meets the
same draws in the same env)."""


def is_randomized(config: BaselineConfig) -> bool:
    """Whether the episodes of ``config`` draw any per-episode randomization."""
    r = config.env.randomization
    return bool(r.enabled and any(getattr(r, kind) for kind in RANDOMIZED))


@dataclass
class EvalReport:
    """What :func:`evaluate_experts` did and found."""

    path: Path
    """The matrix file."""
    matrix: SuccessMatrix
    """This run's objects and expert columns (the file may hold more)."""
    evaluated: int = 0
    """Cells evaluated by this run."""
    reused: int = 0
    """Cells found in the file (resume)."""
    reused_other_code: int = 0
    """Of the reused cells, those another code version ran (another :func:`code_stamp`, or none): same settings,
    but not necessarily the same episodes."""
    errors: list[str] = field(default_factory=list)
    """``object / expert: message`` per cell of this run whose object could not be set up or run."""
    late: list[str] = field(default_factory=list)
    """A line per column of :attr:`matrix` whose episodes often run out of steps (:func:`~ges_core.experts.table.
    late_columns`), from the cells in memory."""
    seconds: float = 0.0

    def table(self, protocol: str = "paper") -> str:
        """Markdown table of success per expert and split, with the baseline and oracle rows."""
        return expert_table(self.matrix, protocol)

    def summary(self) -> str:
        """One line: cells evaluated and reused, errors, time, where the matrix is."""
        m = self.matrix
        other = (
            f" ({self.reused_other_code} run by other code than this, {code_stamp()}: delete them from the matrix "
            "or use another --out to run them again)"
            if self.reused_other_code
            else ""
        )
        return (
            f"{len(m.object_ids)} object(s) x {len(m.experts)} expert(s): {self.evaluated} cell(s) evaluated, "
            f"{self.reused} reused{other}; {len(self.errors)} cell(s) with errors; {self.seconds:.1f} s; "
            f"matrix: {self.path}"
        )


def run_header(config: BaselineConfig) -> dict:
    """What every cell depends on besides its expert and grasp: the config but the record choice and the expert, as
    stored (:func:`~ges_core.config.stored_dump`: a setting added later is left out at what its absence means, so
    cells run before it existed still match)."""
    data = stored_dump(config)
    for key in ("selection", "splits", "expert", "expert_settings"):
        data.pop(key, None)
    return data


def evaluate_experts(
    dataset: str | Path,
    config: BaselineConfig,
    experts: list[ExpertChoice],
    out: str | Path,
    *,
    clusters: str | Path | None = None,
    registry=None,
    progress: bool = False,
    fanout: Fanout | None = None,
    matrix_file: str | Path | None = None,
) -> EvalReport:
    """Evaluate ``experts`` (and the scripted baseline) on the records of ``config.hand`` passing ``config.selection``
    in ``config.splits``, ``config.envs`` episodes per cell; write and return the matrix (module docs).

    clusters: a clusters file (``ges cluster``) or a JSON mapping object id -> cluster; stored per object.
    fanout: where the cells run (:class:`~ges_core.env.evaluate.fanout.Fanout`: executor, workers, address;
    default here, in order); the matrix is written here, after each cell, whichever executor runs it.
    matrix_file: the matrix file to fill (default: :func:`~ges_core.experts.matrix.matrix_path` in ``out``).
    """
    start = time.perf_counter()
    data = open_grasp_dataset(dataset)
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    choices = _columns(experts)
    columns = {c.label: column_identity(registry, c) for c in choices}
    records = config_records(data, config)
    path = (
        Path(matrix_file)
        if matrix_file is not None
        else matrix_path(out, config.hand, config.sim, is_randomized(config))
    )
    matrix = _MatrixFile.open(path, run_header(config), columns, data.root.resolve(), registry)
    matrix.set_objects(records, clusters)
    todo = [(r, c) for r in records for c in choices if not matrix.has(r.object_id, c.label)]
    report = EvalReport(path, matrix.view(records, choices), reused=len(records) * len(choices) - len(todo))
    report.reused_other_code = cells_by_other_code(matrix.data["cells"], records, [c.label for c in choices])
    matrix.write()
    if todo:
        _run_cells(data, registry, config, todo, matrix, report, progress, fanout or Fanout())
    report.matrix = matrix.view(records, choices)
    report.late = late_columns(
        matrix.data["cells"], report.matrix, config.env.episode_length, lift_height=config.env.success.lift_height
    )
    report.seconds = time.perf_counter() - start
    return report


def _columns(experts: list[ExpertChoice]) -> list[ExpertChoice]:
    """The run's columns: the baseline first unless a given expert is labelled like it; labels must be unique."""
    labels = [c.label for c in experts]
    twice = sorted({lab for lab in labels if labels.count(lab) > 1})
    if twice:
        raise ConfigError(f"expert labels {twice} are given twice; label each column once (LABEL=NAME:settings)")
    return experts if BASELINE.label in labels else [BASELINE, *experts]


def column_identity(registry, choice: ExpertChoice) -> dict:
    """A column's identity: registry name, every setting it runs with and, per setting naming a file (a
    checkpoint), the file's content hash (a retrained checkpoint at the same path is another expert)."""
    settings = {**registry.settings("expert", choice.name), **choice.settings}
    files = {k: file_sha256(v) for k, v in settings.items() if isinstance(v, str) and Path(v).is_file()}
    return {"name": choice.name, "settings": settings} | ({"files": files} if files else {})


class _MatrixFile:
    """The matrix file being filled: its JSON (:mod:`~ges_core.experts.matrix`) and where it is written."""

    def __init__(self, path: Path, data: dict, dataset: Path) -> None:
        self.path, self.data, self.dataset = path, data, dataset

    @classmethod
    def open(cls, path: Path, header: dict, columns: dict[str, dict], dataset: Path, registry) -> _MatrixFile:
        """The file at ``path`` (empty if there is none), checked against this run's header and columns (stored
        columns completed by :func:`stored_columns`), with the run's columns added (stored columns first, in their
        order). A stored file without a single cell (left by a run that failed before its first cell finished, e.g.
        with a mistaken setting) holds nothing to keep: it is started over under this run's settings instead of
        refusing them."""
        data = {"run": header, "experts": {}, "baseline": None, "clusters": None, "objects": {}, "cells": {}}
        stored = read_matrix_json(path) if path.is_file() else None
        if stored is not None and any(stored.get("cells", {}).values()):
            data |= stored
            data["experts"] = stored_columns(data.get("experts", {}), registry)
            check_stored_run(path, "success matrix", data, header, columns)
        data["experts"] |= columns
        data["baseline"] = BASELINE.label
        return cls(path, data, dataset)

    def set_objects(self, records, clusters: str | Path | None) -> None:
        """Object entries for ``records`` (dataset order, then objects only earlier runs chose); a changed grasp
        drops the object's cells; a clusters file sets every object's cluster (else the stored one stays)."""
        cluster_of = read_clusters(clusters) if clusters is not None else None
        old, objects = self.data["objects"], {}
        for r in records:
            key, entry = grasp_key(r), old.get(r.object_id, {})
            if entry.get("grasp_key") != key:
                self.data["cells"].pop(r.object_id, None)
            cluster = cluster_of.get(r.object_id) if cluster_of is not None else entry.get("cluster")
            objects[r.object_id] = {"split": r.split, "category": r.category, "cluster": cluster, "grasp_key": key}
        self.data["objects"] = objects | {oid: e for oid, e in old.items() if oid not in objects}
        if clusters is not None:
            self.data["clusters"] = str(Path(clusters).resolve())

    def has(self, object_id: str, label: str) -> bool:
        return label in self.data["cells"].get(object_id, {})

    def put(self, object_id: str, label: str, cell: dict) -> None:
        """Store one cell (an object's cells kept in column order) and rewrite the file."""
        row = {**self.data["cells"].get(object_id, {}), label: cell}
        self.data["cells"][object_id] = {lab: row[lab] for lab in self.data["experts"] if lab in row}
        self.write()

    def write(self) -> None:
        write_matrix(self.path, {"dataset": str(self.dataset), **self.data})

    def view(self, records, choices) -> SuccessMatrix:
        """The matrix of ``records`` (rows) and ``choices`` (columns) only."""
        objects, experts = self.data["objects"], self.data["experts"]
        part = {**self.data, "objects": {r.object_id: objects[r.object_id] for r in records},
                "experts": {c.label: experts[c.label] for c in choices}}  # fmt: skip
        return matrix_from_json(part)


def stored_columns(columns: dict[str, dict], registry) -> dict[str, dict]:
    """Stored expert columns (label -> :func:`column_identity`), each with the settings its expert gained since it
    was written at their defaults (:func:`~ges_core.experts.gained.with_gained_settings`)."""
    return {
        label: {**c, "settings": with_gained_settings(c.get("settings", {}), c.get("name", ""), registry)}
        for label, c in columns.items()
    }


def check_stored_run(path: Path, what: str, stored: dict, header: dict, columns: dict[str, dict]) -> None:
    """ConfigError unless the run settings stored in the file at ``path`` (``stored["run"]``), and every stored
    column this run names (``stored["experts"]``), are this run's. what: the kind of file, for the message."""
    diffs = config_differences(stored.get("run", {}), header)
    if diffs:
        raise ConfigError(
            f"{what} {path} was written with other settings ({'; '.join(diffs)}); choose another --out, "
            "rerun with those settings, or delete the file to start over",
            problems=diffs,
        )
    for label, column in columns.items():
        old = stored.get("experts", {}).get(label)
        if old is not None and old != json.loads(json.dumps(column)):
            diffs = config_differences(old, column)
            raise ConfigError(
                f"expert column '{label}' of {path} was evaluated as {old['name']} with other settings "
                f"({'; '.join(diffs)}); give this one another label (LABEL={column['name']}:...) or use another --out",
                problems=diffs,
            )


def _run_cells(data, registry, config: BaselineConfig, todo, matrix: _MatrixFile, report, progress, fanout) -> None:
    """Evaluate each (record, expert) of ``todo`` (here or on ``fanout``) into ``matrix``, written after each."""
    from tqdm import tqdm

    jobs = [Cell(r.object_id, cell_config(config, c)) for r, c in todo]
    wins = 0
    bar = tqdm(total=len(jobs), disable=not progress, unit="cell", desc=f"{config.hand}/{config.sim}",
               dynamic_ncols=True)  # fmt: skip
    for i, row in evaluate_cells(data, jobs, {r.object_id: r for r, _ in todo}, registry, fanout):
        record, choice = todo[i]
        matrix.put(record.object_id, choice.label, matrix_cell(row))
        report.evaluated += 1
        wins += row["paper_success"]
        if "error" in row:
            report.errors.append(f"{record.object_id} / {choice.label}: {row['error']}")
        bar.update(1)
        bar.set_postfix(success=f"{wins}/{report.evaluated * config.envs}", last=f"{record.object_id}/{choice.label}")
    bar.close()


def cell_config(config: BaselineConfig, choice: ExpertChoice) -> BaselineConfig:
    """``config`` running ``choice``'s expert with its settings."""
    data = {**config.model_dump(), "expert": choice.name, "expert_settings": choice.settings}
    return parse_model(BaselineConfig, data, where=f"expert column '{choice.label}'")


def matrix_cell(row: dict) -> dict:
    """A matrix cell from :func:`evaluate_object`'s row, stamped with the code that ran it (:func:`code_stamp`)."""
    cell = {"episodes": row["envs"], "paper": row["paper_success"], "peers": row["peers_success"]}
    cell |= {k: row[k] for k in ("end_reasons", "max_rise", "steps", "metrics", "seconds") if k in row}
    return cell | ({"error": row["error"]} if "error" in row else {}) | {"code": code_stamp()}


def cells_by_other_code(cells: dict, records, labels) -> int:
    """How many of the ``cells`` (a matrix file's: object id -> label -> cell) of ``records`` x ``labels`` another
    code version ran (another :func:`code_stamp`, or none)."""
    stamp = code_stamp()
    return sum(
        1 for r in records for label in labels
        if (c := cells.get(r.object_id, {}).get(label)) is not None and c.get("code") != stamp
    )  # fmt: skip


CODE_PATHS = ("ges_core", "plugins", "registry.yaml")
"""What runs an episode, for :func:`code_stamp` (paths relative to the checkout's root)."""


@functools.lru_cache(maxsize=1)
def code_stamp() -> str:
    """Which code ran a cell: in a git checkout, the last commit that changed :data:`CODE_PATHS` (12 hex digits)
    plus, when those tracked files differ from HEAD, ``+`` and 8 hex digits of the SHA-256 of that diff; installed,
    ``version X``. A commit of docs, tests or benchmarks alone keeps the stamp (and the matrix reusable).

    Equal settings do not make equal episodes across code versions (a change of how the randomization seeds turn
    into draws changed every episode of a stored matrix, measured in docs/evaluate.md); two cells with one stamp
    were run by the same tracked code. Computed once per process."""
    import ges_core

    root = Path(ges_core.__file__).resolve().parents[1]
    if (root / ".git").exists():
        try:
            return git_code_stamp(root)
        except (OSError, subprocess.SubprocessError):
            pass
    return f"version {ges_core.__version__}"


def git_code_stamp(root: Path) -> str:
    """:func:`code_stamp` of the git checkout at ``root`` (not cached); SubprocessError when git fails."""
    git = {"cwd": root, "capture_output": True, "timeout": 30, "check": True}
    log = ["git", "log", "-1", "--format=%H", "HEAD", "--", *CODE_PATHS]
    commit = subprocess.run(log, text=True, **git).stdout.strip()[:12]
    if not commit:  # no commit touched them (yet)
        commit = subprocess.run(["git", "rev-parse", "HEAD"], text=True, **git).stdout.strip()[:12]
    diff = subprocess.run(["git", "diff", "HEAD", "--", *CODE_PATHS], **git).stdout
    return f"{commit}+{hashlib.sha256(diff).hexdigest()[:8]}" if diff else commit


def code_changes_since(stamp: str, root: Path | None = None) -> list[str] | None:
    """The files of :data:`CODE_PATHS` that differ between the commit of ``stamp`` (a :func:`code_stamp`) and the
    working tree of the git checkout at ``root`` (default: this one): what someone accepting cells of that stamp
    vouches changes no episode. None when it cannot be told (an installed package, a stamp of uncommitted code, a
    commit git does not know)."""
    if root is None:
        import ges_core

        root = Path(ges_core.__file__).resolve().parents[1]
    if "+" in stamp or stamp.startswith("version") or not (root / ".git").exists():
        return None
    try:
        diff = ["git", "diff", "--name-only", stamp, "--", *CODE_PATHS]
        done = subprocess.run(diff, cwd=root, capture_output=True, text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.split()


def read_clusters(path: str | Path) -> dict[str, int]:
    """Object id -> cluster from a clusters file of ``ges cluster`` (format ``ges.object_clusters``, or the
    dataset folder holding one) or from a plain JSON object mapping ids to integers."""
    path = Path(path)
    if path.is_dir() or _format(path) is not None:
        from ges_core.clustering import load_clusters

        return {oid: int(m.cluster) for oid, m in load_clusters(path).objects.items()}
    raw = json.loads(path.read_text())
    if not isinstance(raw, dict) or not all(isinstance(v, int) and not isinstance(v, bool) for v in raw.values()):
        raise AssetError(
            f"{path} is neither a clusters file of ges cluster nor a JSON object mapping object ids to cluster "
            "integers; run 'ges cluster DATASET' and pass DATASET/clusters.json"
        )
    return dict(raw)


def _format(path: Path) -> str | None:
    """The ``format`` key of a JSON file (None if it has none); AssetError if it cannot be read as JSON."""
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"cannot read the clusters file {path}: {exc}") from exc
    return raw.get("format") if isinstance(raw, dict) and isinstance(raw.get("format"), str) else None
