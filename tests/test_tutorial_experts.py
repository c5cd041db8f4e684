"""docs/tutorials/experts.md, run as the page shows it: a six-object Allegro dataset, its clusters, two PPO
experts of two iterations each, the success matrix of both and the scripted baseline (one episode per cell) and a
CurveNet gate on it. Commands are read from the page; the files each one writes and the figures the page states
are checked against the outputs and the matrix.

Real engines at the page's size (6 objects, SAPIEN, 2 envs x 2 iterations, 18 cells, 3 gate epochs): about 70 s
on a quiet 2-core machine (81 s measured at a load average of 1.5).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers_tutorial import commands, console_output, ges_commands, ges_runner, tutorial

from ges_core.experts.matrix import SuccessMatrix, load_matrix

PAGE = tutorial("experts.md")
pytestmark = [pytest.mark.sim, pytest.mark.slow]  # real engines, about 70 s of CPU, 81 s wall
SPLITS = ("train", "unseen_object", "unseen_category")
PAGE_SPLITS = {  # the page, step 1: which objects are in which split
    "procedural/box/003": "train",
    "procedural/can/000": "train",
    "procedural/sphere/000": "train",
    "procedural/sphere/001": "unseen_object",
    "procedural/capsule/000": "unseen_category",
    "procedural/mug/000": "unseen_category",
}


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("experts")


def test_the_page_commands_in_order(folder: Path) -> None:
    ges = ges_runner(folder)
    cmds = ges_commands(PAGE)
    assert len(cmds) == 6, cmds  # a command added to the page needs its check here
    synth, cluster, absolute, residual, evaluate, gate = cmds
    typed = [c for c in commands(PAGE) if c.startswith("ges ")]  # as written, for the outputs shown under them
    dataset = folder / "runs" / "demo" / "dataset"
    experts = folder / "runs" / "demo" / "experts"

    out = ges(*synth)
    assert out.returncode == 0, out.stderr
    assert "| allegro | sapien | 6 |" in out.stdout

    out = ges(*cluster)
    assert out.returncode == 0, out.stderr
    assert (dataset / "clusters.json").is_file() and (dataset / "clusters.png").is_file()
    shown = console_output(PAGE, typed[1]).splitlines()
    printed = out.stdout.splitlines()
    assert printed[:4] == shown[:4], out.stdout  # the cluster table and the one-object warning, as on the page
    clusters = json.loads((dataset / "clusters.json").read_text())
    assert clusters["k"] == 2

    for cmd, name, mode in ((absolute, "expert0", "absolute"), (residual, "expert1", "residual")):
        out = ges(*cmd)
        assert out.returncode == 0, out.stderr
        run = experts / name
        assert f"checkpoint runs/demo/experts/{name}/checkpoints/last.pt" in out.stdout
        assert (run / "checkpoints" / "last.pt").is_file() and (run / "config.yaml").is_file()
        summary = json.loads((run / "summary.json").read_text())
        assert (summary["action_mode"], summary["iterations"], summary["hand"]) == (mode, 2, "allegro")
        assert f"iterations 2, env steps {summary['env_steps']}," in out.stdout

    labels = [a.split("=", 1)[0] for a in _values(evaluate, "--expert")]
    assert labels == ["expert0", "expert1"]
    out = ges(*evaluate)
    assert out.returncode == 0, out.stderr
    matrix_file = experts / "matrix-allegro-sapien.json"
    assert matrix_file.is_file() and f"matrix: runs/demo/experts/{matrix_file.name}" in out.stdout
    assert "6 object(s) x 3 expert(s): 18 cell(s) evaluated, 0 reused;" in out.stdout
    m = load_matrix(matrix_file)
    assert m.complete and m.experts == ("scripted", *labels) and m.baseline == "scripted"
    assert dict(zip(m.object_ids, m.splits, strict=True)) == PAGE_SPLITS
    assert int(m.episodes.min()) == int(m.episodes.max()) == 1  # --episodes 1
    _check_tables(out.stdout, m)
    shown = console_output(PAGE, typed[4])
    _same_but_one_episode(_table(out.stdout, "paper"), _table(shown, "paper"), out.stdout)  # the page's rates
    rates = m.rates("paper")
    # The page: the two-iteration absolute expert lifts nothing (0/6), within one episode as every row above: on
    # another host (same code and packages, 2026-12-06) it lifted the first training object once.
    assert rates[:, m.experts.index("expert0")].sum() <= 1, out.stdout

    no_hand = [a for i, a in enumerate(evaluate) if a != "--hand" and (i == 0 or evaluate[i - 1] != "--hand")]
    out = ges(*no_hand)  # the page: a rerun reuses every cell, and without --hand the dataset's only hand is taken
    assert out.returncode == 0, out.stderr
    assert "0 cell(s) evaluated, 18 reused;" in out.stdout and "matrix-allegro-sapien.json" in out.stdout

    out = ges(*gate)
    assert out.returncode == 0, out.stderr
    run = experts / "gate-curvenet"
    assert (run / "gate.pt").is_file() and (run / "history.json").is_file()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["experts"] == [e for e in m.experts if e != m.baseline]  # the baseline is not a gate choice
    assert out.stdout.startswith("gate curvenet (128 points) over experts expert0, expert1;"), out.stdout
    gate_rows = {row[0]: row[1:] for row in _rows(out.stdout)}
    n_train = sum(s == "train" for s in m.splits)
    assert int(gate_rows["train"][0]) + int(gate_rows["val"][0]) == n_train  # one held out for validation
    learned = [j for j, e in enumerate(m.experts) if e != m.baseline]
    scored = rates[:, learned].max(axis=1) > 0  # objects every learned expert failed are left out of the accuracy
    for split in SPLITS[1:]:
        assert int(gate_rows[split][0]) == sum(s == split and ok for s, ok in zip(m.splits, scored, strict=True))
    for split, (n, acc, *picked) in gate_rows.items():
        assert summary["counts"][split] == int(n)
        assert acc == (f"{100 * summary['accuracy'][split]:.1f} %" if int(n) else "-")  # no object scored: "-"
        assert picked[1] == (f"{100 * summary['picked'][split]['success']:.1f} %" if int(n) else "-")
    assert "pick: always expert1 (" in out.stdout  # the page: one validation object, held by both experts alike
    # the page: expert1 is best on every object, so the gate's 100 % is trivial
    assert (rates[:, m.experts.index("expert1")] >= rates[:, m.experts.index("expert0")]).all()


def _values(args: list[str], flag: str) -> list[str]:
    """Every value given to ``flag`` in an argument list."""
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == flag]


def _rows(text: str) -> list[list[str]]:
    """The body rows of the Markdown tables in ``text`` (header and rule rows left out), cells stripped."""
    rows = [
        [c.strip() for c in line.strip().strip("|").split("|")] for line in text.splitlines() if line.startswith("| ")
    ]
    return [r for r in rows if r[0] not in ("expert", "objects", "hand")]


def _table(text: str, protocol: str) -> dict[str, list[str]]:
    """The ``ges eval-experts`` table of ``protocol`` (``paper``/``peers``): expert label -> cells per split."""
    part = text.split(f"success ({protocol}:", 1)[1].split("\n\n", 2)[1]
    return {row[0]: row[1:] for row in _rows(part)}


def _same_but_one_episode(printed: dict[str, list[str]], shown: dict[str, list[str]], stdout: str) -> None:
    """The printed table is the page's: the same rows, the same episodes (objects for the oracle) per split, and
    each row's successes over the three splits within one episode of the page's. One episode per cell, and the
    unseen sphere's single residual episode is decided by the host's floating point (held on the host the page was
    written on, dropped on another: docs/tutorials/experts.md); a row that moves by more is a real change."""
    assert list(printed) == list(shown), stdout
    for label, cells in printed.items():
        got = [re.search(r"\((\d+)(?:/(\d+)| obj)\)", c).groups() for c in cells[: len(SPLITS)]]
        want = [re.search(r"\((\d+)(?:/(\d+)| obj)\)", c).groups() for c in shown[label][: len(SPLITS)]]
        if label.startswith("oracle"):
            assert [g[0] for g in got] == [w[0] for w in want], (label, cells, stdout)  # objects per split
            continue
        assert [g[1] for g in got] == [w[1] for w in want], (label, cells, stdout)  # episodes per split
        assert sum(abs(int(g[0]) - int(w[0])) for g, w in zip(got, want, strict=True)) <= 1, (label, cells, stdout)


def _check_tables(stdout: str, m: SuccessMatrix) -> None:
    """The printed tables agree with the matrix, and the oracle is at least every expert, split by split."""
    splits = np.array(m.splits)
    for protocol in ("paper", "peers"):
        table = _table(stdout, protocol)
        assert list(table) == ["scripted (baseline)", *m.experts[1:], "oracle (best expert per object)"]
        succ = m.successes[protocol]
        for j, expert in enumerate(m.experts):
            row = table["scripted (baseline)" if expert == m.baseline else expert]
            for k, split in enumerate(SPLITS):
                rows = splits == split
                assert row[k].endswith(f"({succ[rows, j].sum()}/{m.episodes[rows, j].sum()})"), (expert, row)
        oracle = [float(c.split(" %")[0]) for c in table["oracle (best expert per object)"]]
        for label, cells in table.items():
            rates = [float(c.split(" %")[0]) for c in cells]
            assert all(o >= r - 1e-9 for o, r in zip(oracle, rates, strict=True)), (label, cells, oracle)
        best, _ = m.oracle(protocol)
        for k, split in enumerate(SPLITS):
            assert oracle[k] == pytest.approx(100 * best[splits == split].mean(), abs=0.06)
