"""ges evaluate on real episodes (Allegro, SAPIEN, 2 objects, 1 randomized episode per cell): the scripted expert with
two settings as GES's two experts, a centroid gate fitted here so that it picks a different expert per object. Checked
independently: GES's per-object outcome equals running the picked expert alone (the episode runner called directly,
same seeds), a killed run resumes with only the missing cell, the oracle row is at least every expert row, and the
bad inputs fail naming what is wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from helpers_env import grasp_dataset

from ges_core.cli import main
from ges_core.env.evaluate import BaselineConfig
from ges_core.env.evaluate.runner import dataset_scene, evaluate_object
from ges_core.env.grasp_source import library_for, open_grasp_dataset
from ges_core.errors import ArrayError, ConfigError, StorageError
from ges_core.experts import parse_expert
from ges_core.experts.evaluate import RANDOMIZED, cell_config
from ges_core.experts.matrix import PROTOCOLS, load_matrix
from ges_core.gating import GateData, SuccessRates, TrainConfig, library_clouds
from ges_core.ges_eval import GateChoice, evaluate_ges
from ges_core.ges_eval.gates import load_gates, pick_experts
from ges_core.ges_eval.outputs import write_outputs
from ges_core.ges_eval.results import results_path
from ges_core.ges_eval.table import COLUMNS
from ges_core.registry import load_registry

pytestmark = pytest.mark.sim
CANDIDATES = ("procedural/cube/000", "procedural/box/000", "procedural/sphere/000", "procedural/ellipsoid/000")
"""Primitives tried in order until Stage 1 has stored grasps for two (its verdicts change as Stage 1 evolves)."""
EXPERTS = ["scripted", "low=scripted:lift=0.05"]
"""GES's two experts: the scripted baseline and the same script carrying the object only 5 cm up (it meets neither
protocol), so which one the gate picks decides the object's outcome."""


class Registry:
    """The real registry; counts simulators built and, while ``kill_when`` says so, raises KeyboardInterrupt at the
    next build (a kill in the middle of a cell)."""

    def __init__(self, kill_when=None) -> None:
        self.real, self.kill_when, self.sims = load_registry(), kill_when, 0

    def __getattr__(self, name):
        return getattr(self.real, name)

    def build_sim(self, name, scene=None):
        if self.kill_when is not None and self.kill_when():
            raise KeyboardInterrupt
        self.sims += 1
        return self.real.build_sim(name, scene)


def run_config(**kw) -> BaselineConfig:
    data = {"hand": "allegro", "sim": "sapien", "envs": 1, "selection": "any", "env": {"randomization": RANDOMIZED}}
    return BaselineConfig.model_validate(data | kw)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ges_evaluate") / "ds"
    return root, grasp_dataset(root, CANDIDATES)


def fit_gate(dataset_root, ids, experts, path, rates):
    """A centroid gate (one centre per expert, no clustering) fitted on ``rates`` over the objects' real clouds."""
    gate = load_registry().spec("gate", "centroid").load()()
    clouds = library_clouds(library_for(open_grasp_dataset(dataset_root)), ids, 1024)
    gate.fit(GateData(SuccessRates(ids, experts, np.asarray(rates, dtype=float)), clouds), TrainConfig(val_fraction=0))
    gate.save(path)
    return path


@pytest.fixture(scope="module")
def gate(dataset, tmp_path_factory):
    """Fitted to send the first object to 'scripted' and the second to 'low'."""
    root, ids = dataset
    path = tmp_path_factory.mktemp("gate") / "gate.pt"
    return fit_gate(root, ids, ("scripted", "low"), path, [[1.0, 0.0], [0.0, 1.0]])


@pytest.fixture(scope="module")
def run(dataset, gate, tmp_path_factory):
    """GES killed in its second cell, then the same call again: (report, out, matrix file, registry of the rerun)."""
    root, _ = dataset
    out, mfile = tmp_path_factory.mktemp("ges"), tmp_path_factory.mktemp("matrix") / "matrix.json"
    path = results_path(out, "allegro", "sapien")

    def one_cell_written() -> bool:
        return path.is_file() and sum(len(c) for c in json.loads(path.read_text())["cells"].values()) == 1

    experts = [parse_expert(e) for e in EXPERTS]
    with pytest.raises(KeyboardInterrupt):
        evaluate_ges(root, run_config(), experts, [GateChoice(gate)], out, matrix_file=mfile,
                     registry=Registry(one_cell_written))  # fmt: skip
    assert one_cell_written()  # the killed run kept its first cell
    again = Registry()
    report = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], out, matrix_file=mfile, registry=again)
    return report, out, mfile, again


def test_the_gate_picks_per_object_and_a_killed_run_resumes(run, dataset):
    report, _, _, again = run
    _, ids = dataset
    assert report.picks["centroid"].chosen == {ids[0]: "scripted", ids[1]: "low"}
    assert report.matrix_evaluated == 0 and report.matrix_reused == 4  # the killed run had finished the matrix
    assert report.ran == 1 and report.resumed == 1 and report.from_matrix == 0
    assert again.sims == 2  # one cell: the rest pose, then the episodes
    cells = json.loads(report.path.read_text())["cells"]
    assert set(cells[ids[0]]) == {"scripted"} and set(cells[ids[1]]) == {"low"}
    assert all(c["source"] == "run" for row in cells.values() for c in row.values())


def test_ges_equals_the_picked_expert_run_alone_with_the_same_seeds(run, dataset):
    report, _, mfile, _ = run
    root, ids = dataset
    data = open_grasp_dataset(root)
    registry, library = load_registry(), library_for(data)
    hand, scene = registry.build_hand("allegro"), dataset_scene(data, 1)
    cells = json.loads(report.path.read_text())["cells"]
    matrix = json.loads(mfile.read_text())["cells"]
    for oid, choice in zip(ids, (parse_expert(e) for e in EXPERTS), strict=True):
        alone = evaluate_object(registry, hand, data.get(oid, "allegro"), library, cell_config(run_config(), choice),
                                scene)  # fmt: skip
        for cell in (cells[oid][choice.label], matrix[oid][choice.label]):
            assert cell["paper"] == alone["paper_success"] and cell["peers"] == alone["peers_success"]
            assert cell["end_reasons"] == alone["end_reasons"]
            assert cell["max_rise"] == pytest.approx(alone["max_rise"], abs=1e-3)
    # the two experts differ here: the baseline lifts the first object 0.2 m, 'low' carries the second 5 cm only
    assert cells[ids[0]]["scripted"]["max_rise"][0] > 0.15 > cells[ids[1]]["low"]["max_rise"][0]


def test_table_2_rows(run):
    report, out, mfile, _ = run
    table, m = report.table, load_matrix(mfile)
    for p in PROTOCOLS:
        rows = {r["row"]: r for r in table.rows[p]}
        oracle = next(r for r in table.rows[p] if r["kind"] == "oracle")
        ges = rows["GES (centroid)"]
        for split in (s or "all" for s in COLUMNS):
            if oracle["splits"][split]["rate"] is None:
                continue
            for label in ("scripted", "low"):
                assert oracle["splits"][split]["rate"] >= rows[label]["splits"][split]["rate"] - 1e-12
            assert oracle["splits"][split]["rate"] >= ges["splits"][split]["rate"] - 1e-12
        # GES over all objects, by hand from the matrix cells of the picks (the same episodes)
        wins = sum(
            m.successes[p][m.object_ids.index(o), m.column(e)] for o, e in report.picks["centroid"].chosen.items()
        )
        assert ges["splits"]["all"]["successes"] == wins and ges["splits"]["all"]["episodes"] == 2
    assert [r["kind"] for r in table.rows["paper"]] == ["expert", "expert", "oracle", "ges"]  # scripted is an expert
    paths = write_outputs(report, run_config().model_dump(mode="json"))
    assert json.loads(paths["json"].read_text())["rows"] == json.loads(json.dumps(table.rows))
    assert "| GES (centroid) |" in paths["markdown"].read_text()
    import matplotlib.image

    image = matplotlib.image.imread(paths["figure"])
    assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 800


def test_reuse_matrix_takes_the_identical_cells(run, dataset, gate, tmp_path):
    report, _, mfile, _ = run
    root, ids = dataset
    experts = [parse_expert(e) for e in EXPERTS]
    reg = Registry(lambda: True)  # any simulator built is a failure of the test
    again = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path, matrix_file=mfile, registry=reg,
                         reuse_matrix=True)  # fmt: skip
    assert again.from_matrix == 2 and again.ran == 0
    cells = json.loads(again.path.read_text())["cells"]
    matrix = json.loads(mfile.read_text())["cells"]
    assert cells[ids[1]]["low"] == {**matrix[ids[1]]["low"], "source": "matrix"}
    assert again.table.rows == report.table.rows


def test_the_stored_pick_rule_and_the_argmax_side_by_side(run, dataset, gate, tmp_path):
    """A gate whose checkpoint holds a fallback rule picks by it; the same file under --gate-argmax picks by the
    argmax (the fitted centres: a different expert per object). Both rows come from the matrix's cells here."""
    import shutil

    from ges_core.gating.checkpoint import write_pick_rule
    from ges_core.gating.fallback import PickRule

    _, _, mfile, _ = run
    root, ids = dataset
    ruled = tmp_path / "ruled.pt"
    shutil.copy(gate, ruled)
    write_pick_rule(ruled, PickRule("scripted", 1.0, "test: never leave the script"))
    experts = [parse_expert(e) for e in EXPERTS]
    report = evaluate_ges(root, run_config(), experts, [GateChoice(ruled), GateChoice(ruled, argmax=True)],
                          tmp_path / "out", matrix_file=mfile, registry=Registry(lambda: True),
                          reuse_matrix=True)  # fmt: skip
    assert report.picks["centroid"].chosen == {ids[0]: "scripted", ids[1]: "scripted"}
    assert report.picks["centroid-argmax"].chosen == {ids[0]: "scripted", ids[1]: "low"}
    gates = json.loads(report.path.read_text())["gates"]
    assert gates["centroid"]["pick"]["fallback"] == "scripted"
    assert gates["centroid-argmax"]["pick"]["fallback"] is None
    rows = {r["row"]: r for r in report.table.rows["paper"]}
    assert {"GES (centroid)", "GES (centroid-argmax)"} <= set(rows)
    write_pick_rule(ruled, PickRule("nope", 0.5))
    with pytest.raises(ConfigError, match="'nope' is not one of the gate's"):
        load_gates([GateChoice(ruled)], load_registry(), ["scripted", "low"])


def _stamped_copy(mfile, object_id: str, tmp_path):
    """The matrix file's JSON with its ``low`` cell of ``object_id`` stamped as run by code 0123456789ab, and the path
    of a copy holding it: (raw, path)."""
    raw = json.loads(mfile.read_text())
    raw["cells"][object_id]["low"]["code"] = "0123456789ab"
    copy = tmp_path / "matrix.json"
    copy.write_text(json.dumps(raw))
    return raw, copy


def test_reuse_matrix_runs_a_cell_that_other_code_made(run, dataset, gate, tmp_path):
    """Equal settings under other code are not the same episodes: such a matrix cell is run, not reused."""
    _, _, mfile, _ = run
    root, ids = dataset
    raw, copy = _stamped_copy(mfile, ids[1], tmp_path)
    reg = Registry()
    again = evaluate_ges(root, run_config(), [parse_expert(e) for e in EXPERTS], [GateChoice(gate)], tmp_path,
                         matrix_file=copy, registry=reg, reuse_matrix=True)  # fmt: skip
    assert (again.from_matrix, again.ran, reg.sims, again.matrix_other_code) == (1, 1, 2, 1)
    cells = json.loads(again.path.read_text())["cells"]
    assert cells[ids[0]]["scripted"]["source"] == "matrix" and cells[ids[1]]["low"]["source"] == "run"
    assert "1 matrix cell(s) and 0 resumed GES cell(s) were run by other code" in again.summary()


def test_accept_code_takes_the_cells_of_a_named_other_code_and_only_those(run, dataset, gate, tmp_path):
    """--accept-code STAMP: the matrix's cells of that stamp are taken (keeping their stamp), cells of any other
    code still run; a later run that does not name the stamp runs the cell it had taken; the flag alone is refused."""
    _, _, mfile, _ = run
    root, ids = dataset
    raw, copy = _stamped_copy(mfile, ids[1], tmp_path)
    experts = [parse_expert(e) for e in EXPERTS]
    kw = {"matrix_file": copy, "reuse_matrix": True}
    taken = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "a",
                         registry=Registry(lambda: True), accept_code=["0123456789ab"], **kw)  # fmt: skip
    assert (taken.from_matrix, taken.from_accepted_code, taken.ran) == (2, {"0123456789ab": 1}, 0)
    cell = json.loads(taken.path.read_text())["cells"][ids[1]]["low"]
    assert cell == {**raw["cells"][ids[1]]["low"], "source": "matrix"}  # its own stamp, not this code's
    assert "2 taken from the matrix (identical settings and code; 1 of them run by code accepted" in taken.summary()
    assert "cells run by code 0123456789ab counted as this code's (--accept-code: 1 taken)" in taken.summary()
    other = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "b", registry=Registry(),
                         accept_code=["fedcba987654"], **kw)  # fmt: skip
    assert (other.from_matrix, other.from_accepted_code, other.ran) == (1, {}, 1)
    reg = Registry()
    again = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "a", registry=reg, **kw)
    assert (again.from_matrix, again.ran, reg.sims) == (1, 1, 2)  # the taken cell is not kept without the stamp
    verified = evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "v", registry=Registry(),
                            accept_code=["0123456789ab"], verify_accepted=3, **kw)  # fmt: skip
    assert verified.verified == [f"{ids[1]} / low"] and verified.from_accepted_code == {"0123456789ab": 1}
    assert verified.ran == 0 and "verified: 1 accepted cell(s) rerun by this code gave the same episodes" in (
        verified.summary()
    )
    raw["cells"][ids[1]]["low"]["max_rise"] = [x + 0.001 for x in raw["cells"][ids[1]]["low"]["max_rise"]]
    copy.write_text(json.dumps(raw))  # the same stamp, other episodes: as if the code since had changed them
    with pytest.raises(ConfigError, match=rf"1 of 1 sampled cell\(s\).*{ids[1]} / low \(code 0123456789ab: max_rise"):
        evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "w", registry=Registry(),
                     accept_code=["0123456789ab"], verify_accepted=1, **kw)  # fmt: skip
    assert not json.loads(results_path(tmp_path / "w", "allegro", "sapien").read_text())["cells"].get(ids[1])
    with pytest.raises(ConfigError, match="only matters with reuse_matrix"):
        evaluate_ges(root, run_config(), experts, [GateChoice(gate)], tmp_path / "c", matrix_file=copy,
                     accept_code=["0123456789ab"])  # fmt: skip


def test_a_results_file_of_other_settings_is_refused(run, dataset, gate):
    report, out, mfile, _ = run
    root, _ = dataset
    raw = json.loads(report.path.read_text())
    raw["run"]["seed"] = 7
    report.path.write_text(json.dumps(raw))
    try:
        with pytest.raises(ConfigError, match=r"other settings \(seed: 7 -> 0\)"):
            evaluate_ges(root, run_config(), [parse_expert(e) for e in EXPERTS], [GateChoice(gate)], out,
                         matrix_file=mfile, registry=Registry(lambda: True))  # fmt: skip
    finally:
        raw["run"]["seed"] = 0
        report.path.write_text(json.dumps(raw))


def test_a_gate_for_other_experts_is_refused_naming_both_lists(gate, dataset):
    with pytest.raises(ConfigError) as err:
        load_gates([GateChoice(gate)], load_registry(), ["scripted", "lower"])
    assert "['scripted', 'low']" in str(err.value) and "['scripted', 'lower']" in str(err.value)
    # the order of --expert is free: the same experts in another order are the gate's
    assert load_gates([GateChoice(gate)], load_registry(), ["low", "scripted"])[0].label == "centroid"


def test_bad_clouds_and_gate_files_name_the_culprit(gate, dataset, tmp_path):
    _, ids = dataset
    loaded = load_gates([GateChoice(gate)], load_registry(), ["scripted", "low"])[0]
    good = np.random.default_rng(0).normal(size=(1024, 3)) * 0.03
    nan = good.copy()
    nan[5] = np.nan
    with pytest.raises(ArrayError, match=r"object 'shelf/vase': 1 of 1024 points are NaN"):
        pick_experts(loaded, [good, nan], ["shelf/cup", "shelf/vase"])
    with pytest.raises(ArrayError, match=r"object 'shelf/empty': point cloud is empty"):
        pick_experts(loaded, [np.zeros((0, 3))], ["shelf/empty"])
    one = pick_experts(loaded, torch.from_numpy(good[None]).float(), ["shelf/cup"])  # a good cloud is fine
    assert one.chosen["shelf/cup"] in ("scripted", "low") and sum(one.scores["shelf/cup"]) == pytest.approx(1.0)
    with pytest.raises(StorageError, match="--gate .*nowhere.pt: no such file"):
        load_gates([GateChoice(tmp_path / "nowhere.pt")], load_registry(), ["scripted", "low"])
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="junk.pt is not a readable gate checkpoint"):
        load_gates([GateChoice(tmp_path / "junk.pt")], load_registry(), ["scripted", "low"])
    with pytest.raises(ConfigError, match=r"gates labelled \['g'\] more than once"):
        load_gates([GateChoice(gate, "g"), GateChoice(gate, "g")], load_registry(), ["scripted", "low"])


def test_cli(run, dataset, gate, tmp_path, capsys):
    _, _, mfile, _ = run
    root, _ = dataset
    base = ["evaluate", str(root), "--hand", "allegro", "--sim", "sapien", "--episodes", "1", "--select", "any",
            "--matrix", str(mfile), "--out", str(tmp_path), "--no-progress"]  # fmt: skip
    experts = ["--expert", "scripted", "--expert", "low=scripted:lift=0.05"]
    assert main([*base, *experts, "--gate", str(gate), "--reuse-matrix"]) == 0
    out = capsys.readouterr().out
    assert "| GES (centroid) |" in out and "| oracle (best of scripted, low per object) |" in out
    assert "2 taken from the matrix (identical settings and code)" in out
    assert "GES against the best single expert of each split" in out and "too few objects" in out  # 2 objects
    notes = [line for line in out.splitlines() if line.startswith("note: expert ")]
    assert len(notes) == 1 and notes[0].startswith("note: expert 'low': 2 of 2 episodes (100 %) ran out")  # 5 cm up
    assert (tmp_path / "fusion-allegro-sapien.png").stat().st_size > 10_000
    assert main([*base, *experts, "--gate", str(tmp_path / "none.pt")]) == 1
    assert "none.pt: no such file" in capsys.readouterr().err
    assert main([*base, "--expert", "scripted", "--expert", "lower=scripted:lift=0.05", "--gate", str(gate)]) == 1
    assert "trained for experts ['scripted', 'low'] but is used with ['scripted', 'lower']" in capsys.readouterr().err


def test_cli_takes_the_experts_from_the_gate(run, dataset, gate, tmp_path, capsys):
    """Without --expert, `ges evaluate` runs the experts the gate was trained for: the columns of the matrix that
    `ges train-gate` names in summary.json beside the checkpoint, on that matrix's hand, simulator and episodes per
    cell. The matrix's cells are then reused as with the same options given by hand (reuse needs identical settings
    and run header). A gate alone whose label is not an expert text ('low') is refused, naming its experts."""
    import shutil

    _, _, mfile, _ = run
    root, _ = dataset
    base = ["evaluate", str(root), "--hand", "allegro", "--sim", "sapien", "--episodes", "1", "--select", "any",
            "--matrix", str(mfile), "--no-progress", "--reuse-matrix"]  # fmt: skip
    alone = tmp_path / "alone" / "gate.pt"
    alone.parent.mkdir()
    shutil.copy(gate, alone)
    assert main([*base, "--out", str(tmp_path / "a"), "--gate", str(alone)]) == 1
    err = capsys.readouterr().err
    assert "trained for the experts ['scripted', 'low']; 'low' is not an expert text" in err and "--expert" in err
    (alone.parent / "summary.json").write_text(json.dumps({"config": {"matrix": str(mfile)}}))
    # no --hand, --sim, --episodes or --matrix either: the training matrix's
    bare = ["evaluate", str(root), "--select", "any", "--no-progress", "--reuse-matrix", "--out", str(tmp_path / "b")]
    assert main([*bare, "--gate", str(alone)]) == 0
    out = capsys.readouterr().out
    assert f"experts from gate {alone}: scripted, low" in out
    assert f"from the gate's training matrix {mfile}: --hand allegro, --sim sapien, --episodes 1, its seed 0" in out
    assert f"--matrix {mfile} (the gate's training matrix, same run settings)" in out
    assert "| oracle (best of scripted, low per object) |" in out and "2 taken from the matrix" in out
    assert "was trained on the success rates of" not in out  # the run is the gate's own hand and simulator
    assert "randomized start pose" in out

    # a matrix run with another seed and without randomization: those settings are the run's too (before, the run
    # took the defaults and refused to complete the matrix, naming seed). The header is edited rather than rerun:
    # what is tested is which settings the command takes, and the matrix's cells are reused only under equal headers
    data = json.loads(mfile.read_text())
    data["run"]["seed"] = 7
    data["run"]["env"]["randomization"]["enabled"] = False
    other = tmp_path / "seed7" / "matrix.json"
    other.parent.mkdir()
    other.write_text(json.dumps(data))
    (alone.parent / "summary.json").write_text(json.dumps({"config": {"matrix": str(other)}}))
    assert main([*bare[:-1], str(tmp_path / "c"), "--gate", str(alone)]) == 0
    out = capsys.readouterr().out
    assert "its seed 7" in out and f"--matrix {other} (the gate's training matrix, same run settings)" in out
    assert "randomization off" in out and "2 taken from the matrix" in out
    assert json.loads(results_path(tmp_path / "c", "allegro", "sapien", False).read_text())["run"]["seed"] == 7
    # asking for other settings (here -o seed=8) keeps the default matrix file and names what differs
    import argparse

    from ges_core.cli.cmd_evaluate import _matrix_from_training

    args = argparse.Namespace(matrix=None)
    _matrix_from_training(args, run_config(seed=8, env=data["run"]["env"]), other, data["run"])
    assert args.matrix is None and "(its run differs: seed: 7 -> 8)" in capsys.readouterr().out
    _matrix_from_training(args, run_config(seed=7, env=data["run"]["env"]), other, data["run"])
    assert args.matrix == other


def test_a_gate_used_for_another_hand_or_simulator_is_noted(run, gate, tmp_path):
    """A gate's picks come from its training matrix's hand and simulator: used for another one, `ges evaluate` says
    so (it runs: carrying a gate over may be meant). The hand and simulator are read from the matrix file that
    summary.json names, not assumed; a gate without one gets no note."""
    import shutil

    from ges_core.ges_eval.gates import transfer_notes

    _, _, mfile, _ = run
    moved = tmp_path / "g" / "gate.pt"
    moved.parent.mkdir()
    shutil.copy(gate, moved)
    choice = GateChoice(moved)
    assert transfer_notes([choice], "shadow", "sapien") == []  # no summary.json: nothing known
    (moved.parent / "summary.json").write_text(json.dumps({"matrix": str(mfile)}))
    header = json.loads(mfile.read_text())["run"]
    assert (header["hand"], header["sim"]) == ("allegro", "sapien")
    assert transfer_notes([choice], "allegro", "sapien") == []
    [hand] = transfer_notes([choice], "shadow", "sapien")
    assert "trained on the success rates of allegro in sapien" in hand and "this run is shadow in sapien" in hand
    assert hand.endswith("another hand") and str(mfile) in hand
    [both] = transfer_notes([choice, GateChoice(gate)], "shadow", "pybullet")
    assert both.endswith("another hand and simulator")
