"""``ges evaluate``: GES end to end. Per object each gate reads the cloud and picks one expert; the pre-grasp reaching
runs and the picked expert executes, E episodes; Table 2 sets GES beside every expert, the baseline and the oracle.

>>> report = evaluate_ges("runs/tiny/dataset", config, experts, [parse_gate("runs/tiny/gate/gate.pt")], "runs/tiny/ges",
...                       matrix_file="runs/tiny/eval/matrix-allegro-sapien.json")
>>> print(report.table.markdown("paper"))

Steps: (1) the success matrix of the experts alone (and the scripted baseline) is completed for the run's objects
by :func:`ges_core.experts.evaluate.evaluate_experts` under the same settings (a matrix of other settings is
refused; cells it holds are reused, as ``ges eval-experts`` resumes); (2) each gate picks per object
(:mod:`~ges_core.ges_eval.gates`); (3) the episodes of every (object, picked expert) run through the episode runner
of ``ges eval-experts`` (:func:`ges_core.env.evaluate.fanout.evaluate_cells`, a fresh simulator per cell: stage-one
reaching, then the expert), the results file (:mod:`~ges_core.ges_eval.results`) rewritten after each; (4) Table 2
(:mod:`~ges_core.ges_eval.table`). With ``reuse_matrix`` step 3 takes the matrix cell of the picked expert instead
of running it when the episodes would be the same ones: step 1 has proven the settings identical (run header, expert
identity with checkpoint hashes, grasp key) and the cell carries this code's
:func:`~ges_core.experts.evaluate.code_stamp` (equal settings under other code gave other episodes: a change of the
randomization streams changed every one); the cell is marked ``source: matrix`` and the summary says how many.
``accept_code`` adds stamps of other code whose cells count as this code's, on the caller's word (say, only gate
code changed since, which picks experts but runs no episode): the cell keeps its stamp and the summary lists the
code files that differ.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ges_core.env.evaluate import BaselineConfig, config_records
from ges_core.env.evaluate.fanout import Cell, Fanout, evaluate_cells
from ges_core.env.grasp_source import library_for, open_grasp_dataset
from ges_core.errors import ConfigError
from ges_core.experts.choice import ExpertChoice
from ges_core.experts.evaluate import (
    cell_config,
    cells_by_other_code,
    code_changes_since,
    code_stamp,
    column_identity,
    evaluate_experts,
    is_randomized,
    matrix_cell,
    run_header,
)
from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix, matrix_path, read_matrix_json
from ges_core.ges_eval.against_best import ges_against_best
from ges_core.ges_eval.gates import GateChoice, LoadedGate, Picks, clouds_for, load_gates, pick_experts
from ges_core.ges_eval.results import ResultsFile, results_path
from ges_core.ges_eval.table import GesRow, Table2, table2

__all__ = ["GesReport", "evaluate_ges", "ges_row"]


@dataclass
class GesReport:
    """What :func:`evaluate_ges` did and found."""

    path: Path
    """The results file."""
    matrix_path: Path
    table: Table2
    matrix: SuccessMatrix
    """The matrix view of the run: its objects, the baseline and the GES experts."""
    picks: dict[str, Picks]
    """Gate label -> what it picked."""
    ges_rows: list[GesRow] = field(default_factory=list)
    """Per gate: its GES episodes per object (rows of ``matrix``)."""
    matrix_evaluated: int = 0
    matrix_reused: int = 0
    ran: int = 0
    """GES cells whose episodes this run ran."""
    resumed: int = 0
    """GES cells found in the results file."""
    from_matrix: int = 0
    """GES cells taken from the matrix (``reuse_matrix``: identical settings and code, or code of ``accept_code``)."""
    accepted_code: dict[str, list[str] | None] = field(default_factory=dict)
    """``accept_code``: stamp -> the code files that differ between it and this code (None: not known)."""
    from_accepted_code: dict[str, int] = field(default_factory=dict)
    """Of :attr:`from_matrix`, how many cells each stamp of ``accept_code`` ran."""
    verified: list[str] = field(default_factory=list)
    """``object / expert`` of the accepted cells rerun by this code and found identical (``verify_accepted``)."""
    matrix_other_code: int = 0
    """Cells of the run's matrix rows and columns that other code ran (another :func:`code_stamp`, or none)."""
    resumed_other_code: int = 0
    """Resumed GES cells that other code ran."""
    errors: list[str] = field(default_factory=list)
    late: list[str] = field(default_factory=list)
    """The matrix run's :attr:`~ges_core.experts.evaluate.EvalReport.late` lines (columns that run out of steps)."""
    seconds: float = 0.0
    against_best: list = field(default_factory=list)
    """Per split and gate (paper protocol): ``(best single expert, BaselineDifference of GES against it)``
    (:func:`ges_core.ges_eval.against_best.ges_against_best`)."""

    def _accepted(self) -> str:
        n = sum(self.from_accepted_code.values())
        return f"; {n} of them run by code accepted with --accept-code" if n else ""

    def summary(self) -> str:
        """Lines: objects, gates, cells run / resumed / reused, errors, time and where the files are."""
        m = self.matrix
        lines = [
            f"{len(m.object_ids)} object(s), {len(self.picks)} gate(s) over experts {', '.join(self.table.experts)}",
            f"matrix {self.matrix_path}: {self.matrix_evaluated} cell(s) evaluated, {self.matrix_reused} reused",
            f"GES {self.path}: {self.ran} cell(s) run, {self.resumed} resumed"
            + (
                f", {self.from_matrix} taken from the matrix (identical settings and code{self._accepted()})"
                if self.from_matrix
                else ""
            ),  # fmt: skip
            f"{len(self.errors)} cell(s) with errors; {self.seconds:.1f} s",
        ]
        if self.verified:
            lines.append(f"verified: {len(self.verified)} accepted cell(s) rerun by this code gave the same episodes "
                         f"({', '.join(self.verified)})")  # fmt: skip
        for stamp, changed in self.accepted_code.items():
            files = "not known" if changed is None else (", ".join(changed) or "none")
            lines.append(
                f"note: cells run by code {stamp} counted as this code's (--accept-code: "
                f"{self.from_accepted_code.get(stamp, 0)} taken); code files changed since: {files}"
            )
        if self.matrix_other_code or self.resumed_other_code:
            lines.append(
                f"note: {self.matrix_other_code} matrix cell(s) and {self.resumed_other_code} resumed GES cell(s) were "
                f"run by other code than this ({code_stamp()}): same settings, but not necessarily the same episodes"
            )
        return "\n".join(lines)


def evaluate_ges(
    dataset: str | Path,
    config: BaselineConfig,
    experts: list[ExpertChoice],
    gates: list[GateChoice],
    out: str | Path,
    *,
    matrix_file: str | Path | None = None,
    registry=None,
    progress: bool = False,
    fanout: Fanout | None = None,
    reuse_matrix: bool = False,
    accept_code: Sequence[str] = (),
    verify_accepted: int = 0,
    cloud_seed: int = 0,
) -> GesReport:
    """Run GES with each gate on the records of ``config.hand`` passing ``config.selection`` in ``config.splits``
    (module docs); write ``out``/ges-HAND-SIM.json and return the report with Table 2.

    experts: the experts GES chooses among, labelled as in the matrix and the gates' checkpoints (the scripted
    baseline is added to the matrix unless one is labelled ``scripted``). matrix_file: the success matrix to
    complete and compare against (default: ``ges eval-experts``' file, DATASET/../experts/matrix-HAND-SIM.json).
    cloud_seed: seed of the surface samples each gate's cloud is drawn from (``ges train-gate``'s, 0).
    accept_code: with ``reuse_matrix``, code stamps (:func:`~ges_core.experts.evaluate.code_stamp`) whose matrix cells
    count as this code's: the caller vouches that nothing between them changes an episode (e.g. only gate code
    changed); the report lists the code files that differ (:attr:`GesReport.accepted_code`). verify_accepted: rerun
    that many of the cells about to be taken under an ``accept_code`` stamp (spread over the objects) with this code
    first; any that differs from the matrix's (successes, end reasons, highest rise, steps) is a ConfigError naming it,
    and nothing is taken.
    """
    if accept_code and not reuse_matrix:
        raise ConfigError("accept_code (--accept-code) only matters with reuse_matrix (--reuse-matrix)")
    start = time.perf_counter()
    registry = registry if registry is not None else _default_registry()
    data = open_grasp_dataset(dataset)
    labels = tuple(c.label for c in experts)
    loaded = load_gates(gates, registry, labels)
    records = _records(data, config, dataset)
    picks = _pick_all(loaded, library_for(data), [r.object_id for r in records], cloud_seed)  # bad clouds fail early
    mfile = Path(matrix_file) if matrix_file is not None else _default_matrix(data.root, config)
    mreport = evaluate_experts(data.root, config, experts, mfile.parent, registry=registry, progress=progress,
                               fanout=fanout, matrix_file=mfile)  # fmt: skip
    columns = {c.label: column_identity(registry, c) for c in experts}
    results = ResultsFile.open(results_path(out, config.hand, config.sim, is_randomized(config)), run_header(config),
                               columns, data.root.resolve(), mfile.resolve(), registry)  # fmt: skip
    results.set_objects(records)
    for g in loaded:
        results.set_gate(g.label, g.describe(), picks[g.label])
    results.write()
    report = GesReport(results.path, mfile, Table2(), mreport.matrix, picks)
    report.matrix_evaluated, report.matrix_reused = mreport.evaluated, mreport.reused
    report.late = mreport.late
    matrix_cells = read_matrix_json(mfile).get("cells", {})  # the file as evaluate_experts left it, read once
    report.matrix_other_code = cells_by_other_code(matrix_cells, records, columns)
    choices, fanout = {c.label: c for c in experts}, fanout or Fanout()
    accepted = {code_stamp(), *accept_code} if reuse_matrix else set()
    report.accepted_code = {s: code_changes_since(s) for s in accept_code if s != code_stamp()}
    todo = _todo(records, picks, results, report, accepted)
    if reuse_matrix:
        sample = _accepted_sample(todo, matrix_cells, accepted - {code_stamp()}, verify_accepted)
        _verify(data, registry, config, choices, sample, matrix_cells, report, fanout)
        todo = _take_from_matrix(todo, matrix_cells, results, report, accepted)
    _run(data, registry, config, choices, todo, results, report, progress, fanout)
    report.ges_rows = [ges_row(mreport.matrix, g.label, picks[g.label].chosen, results) for g in loaded]
    report.table = table2(mreport.matrix, labels, report.ges_rows)
    report.against_best = ges_against_best(mreport.matrix, report.ges_rows, labels)
    report.seconds = time.perf_counter() - start
    return report


def _default_registry():
    from ges_core.registry import load_registry

    return load_registry()


def _default_matrix(root: Path, config: BaselineConfig) -> Path:
    return matrix_path(root.parent / "experts", config.hand, config.sim, is_randomized(config))


def _records(data, config: BaselineConfig, dataset) -> list:
    records = config_records(data, config)
    if not records:
        raise ConfigError(
            f"dataset {dataset} has no '{config.selection}' records of hand '{config.hand}' in splits "
            f"{list(config.splits)}; check --hand, --select and --split"
        )
    return records


def _pick_all(gates: list[LoadedGate], library, ids: list[str], seed: int) -> dict[str, Picks]:
    """Each gate's picks; clouds sampled once per size (an object with an empty or NaN cloud: ArrayError naming it)."""
    clouds: dict[int, object] = {}
    out = {}
    for g in gates:
        if g.n_points not in clouds:
            clouds[g.n_points] = clouds_for(library, ids, g.n_points, seed)
        out[g.label] = pick_experts(g, clouds[g.n_points], ids)
    return out


def _todo(records, picks: dict[str, Picks], results: ResultsFile, report: GesReport, accepted: set[str]) -> list[tuple]:
    """(record, expert label) of every pick without a cell in the results file, in record order, each once; a cell
    an earlier run took from the matrix counts as missing unless this run reuses the matrix too and accepts the code
    that ran it (``accepted``: code stamps, empty without ``reuse_matrix``)."""
    todo, seen = [], set()
    for r in records:
        for p in picks.values():
            key = (r.object_id, p.chosen[r.object_id])
            if key in seen:
                continue
            seen.add(key)
            cell = results.cell(*key)
            if cell is None or (cell.get("source") == "matrix" and cell.get("code") not in accepted):
                todo.append((r, key[1]))
            elif cell.get("source") == "matrix":
                report.from_matrix += 1
                _count_accepted(report, cell)
            else:
                report.resumed += 1
                report.resumed_other_code += cell.get("code") != code_stamp()
    return todo


def _take_from_matrix(
    todo: list[tuple], cells: dict, results: ResultsFile, report: GesReport, accepted: set[str]
) -> list[tuple]:
    """Store the matrix's cell (``cells``: the matrix file's) for each (record, expert) it holds that this code ran
    (settings proven identical by the matrix run's checks, code by :func:`code_stamp`) or code of ``accepted`` (the
    cell keeps its own stamp); return the rest, to run."""
    rest = []
    for r, label in todo:
        cell = cells.get(r.object_id, {}).get(label)
        if not _takeable(cell, accepted):
            rest.append((r, label))
            continue
        results.put(r.object_id, label, {**cell, "source": "matrix"})
        report.from_matrix += 1
        _count_accepted(report, cell)
    return rest


def _takeable(cell: dict | None, stamps: set[str]) -> bool:
    """Whether a matrix cell can stand for a GES cell: it exists, has no error, and code of ``stamps`` ran it."""
    return cell is not None and "error" not in cell and cell.get("code") in stamps


SAME_EPISODES = ("episodes", "paper", "peers", "end_reasons", "max_rise", "steps")
"""What two cells of the same settings share when they ran the same episodes (:func:`_verify`)."""


def _accepted_sample(todo: list[tuple], cells: dict, stamps: set[str], n: int) -> list[tuple]:
    """Up to ``n`` of ``todo``'s (record, label) whose matrix cell (``cells``) another code of ``stamps`` ran, spread
    evenly over them in record order."""
    candidates = [(r, label) for r, label in todo if _takeable(cells.get(r.object_id, {}).get(label), stamps)]
    if n <= 0 or not candidates:
        return []
    picks = np.unique(np.linspace(0, len(candidates) - 1, min(n, len(candidates))).round().astype(int))
    return [candidates[i] for i in picks]


def _verify(data, registry, config, choices, sample: list[tuple], cells: dict, report: GesReport, fanout) -> None:
    """Rerun ``sample``'s cells with this code; a ConfigError naming every one whose episodes differ from the
    matrix's cell (:data:`SAME_EPISODES`)."""
    differ = []
    for (record, label), row in _evaluated(data, registry, config, choices, sample, fanout):
        stored, now = cells[record.object_id][label], matrix_cell(row)
        keys = [k for k in SAME_EPISODES if stored.get(k) != now.get(k)]
        name = f"{record.object_id} / {label}"
        if keys:
            differ.append(f"{name} (code {stored.get('code')}: {', '.join(keys)} differ)")
        else:
            report.verified.append(name)
    if differ:
        raise ConfigError(
            f"--accept-code: {len(differ)} of {len(sample)} sampled cell(s) rerun by this code ({code_stamp()}) gave "
            f"other episodes than the matrix's: {'; '.join(differ)}. The code since that stamp changes episodes: "
            "drop --accept-code and run the cells (or evaluate a new --matrix with this code)"
        )


def _count_accepted(report: GesReport, cell: dict) -> None:
    """Count ``cell``, taken from the matrix, under its stamp when another code than this ran it (accept_code)."""
    if (stamp := cell.get("code")) != code_stamp():
        report.from_accepted_code[stamp] = report.from_accepted_code.get(stamp, 0) + 1


def _run(data, registry, config, choices: dict[str, ExpertChoice], todo, results, report, progress, fanout) -> None:
    """Run each (record, expert label) of ``todo`` here or on ``fanout``; the results file rewritten after each."""
    from tqdm import tqdm

    if not todo:
        return
    bar = tqdm(total=len(todo), disable=not progress, unit="cell", desc="GES", dynamic_ncols=True)
    wins = 0
    for (record, label), row in _evaluated(data, registry, config, choices, todo, fanout):
        results.put(record.object_id, label, {**matrix_cell(row), "source": "run"})
        report.ran += 1
        wins += row["paper_success"]
        if "error" in row:
            report.errors.append(f"{record.object_id} / {label}: {row['error']}")
        bar.update(1)
        bar.set_postfix(success=f"{wins}/{report.ran * config.envs}", last=f"{record.object_id}/{label}")
    bar.close()


def _evaluated(data, registry, config, choices: dict[str, ExpertChoice], pairs: list[tuple], fanout):
    """((record, expert label), row of the episode runner) for each pair of ``pairs``, as each finishes (none: no
    worker pool is started)."""
    if not pairs:
        return
    jobs = [Cell(r.object_id, cell_config(config, choices[label])) for r, label in pairs]
    for i, row in evaluate_cells(data, jobs, {r.object_id: r for r, _ in pairs}, registry, fanout):
        yield pairs[i], row


def ges_row(matrix: SuccessMatrix, label: str, chosen: dict[str, str], results: ResultsFile) -> GesRow:
    """Gate ``label``'s episodes per object of ``matrix`` (its rows) from the results file, ``chosen``: object id ->
    the expert label the gate picked (:attr:`Picks.chosen`, or a stored results file's ``gates[label]["picks"]``)."""
    n = len(matrix.object_ids)
    episodes = np.zeros(n, dtype=np.int64)
    wins = {p: np.zeros(n, dtype=np.int64) for p in PROTOCOLS}
    picked = np.zeros(n, dtype=np.int64)
    for i, oid in enumerate(matrix.object_ids):
        picked[i] = matrix.column(chosen[oid])
        cell = results.cell(oid, chosen[oid])
        if cell is not None:
            episodes[i] = cell["episodes"]
            for p in PROTOCOLS:
                wins[p][i] = cell[p]
    return GesRow(label, wins, episodes, picked)
