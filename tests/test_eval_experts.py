"""ges eval-experts on real episodes (Allegro, SAPIEN, 2 objects, the scripted expert with two settings as two
experts, 2 randomized episodes per cell): the matrix, its reader, the oracle, resume after a kill, refusals, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers_env import grasp_dataset

from ges_core.cli import main
from ges_core.dataset import open_dataset
from ges_core.env.evaluate import BaselineConfig
from ges_core.env.evaluate.fanout import Fanout
from ges_core.errors import AssetError, ConfigError, UnknownNameError
from ges_core.experts import parse_expert
from ges_core.experts.compare import pool_matrices
from ges_core.experts.evaluate import RANDOMIZED, evaluate_experts
from ges_core.experts.matrix import load_matrix, matrix_path
from ges_core.experts.table import expert_table, split_rates
from ges_core.registry import load_registry

pytestmark = pytest.mark.sim
CANDIDATES = ("procedural/cube/000", "procedural/box/000", "procedural/sphere/000", "procedural/ellipsoid/000")
"""Primitives tried in order until Stage 1 has stored grasps for two (its verdicts change as Stage 1 evolves)."""
EXPERTS = ["scripted", "low=scripted:lift=0.05"]
"""The baseline, and the same script carrying the object only 5 cm up: it can meet neither protocol (0.2 m up;
within 5 cm of the 0.2 m target), so the two columns differ and the oracle has something to choose."""


class InterruptingRegistry:
    """The real registry, but the simulator build number ``stop_at`` raises KeyboardInterrupt (a kill mid-run)."""

    def __init__(self, stop_at: int | None = None, refuse: bool = False) -> None:
        self.real, self.stop_at, self.refuse, self.sims = load_registry(), stop_at, refuse, 0

    def __getattr__(self, name):
        return getattr(self.real, name)

    def build_sim(self, name, scene=None):
        if self.refuse:
            raise AssertionError("this run should not build a simulator")
        self.sims += 1
        if self.sims == self.stop_at:
            raise KeyboardInterrupt
        return self.real.build_sim(name, scene)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval_experts") / "ds"
    grasp_dataset(root, CANDIDATES)
    return root


def run_config(**kw) -> BaselineConfig:
    data = {"hand": "allegro", "sim": "sapien", "envs": 2, "selection": "any", "env": {"randomization": RANDOMIZED}}
    return BaselineConfig.model_validate(data | kw)


@pytest.fixture(scope="module")
def full(dataset, tmp_path_factory):
    """One uninterrupted run: (report, out folder, clusters given)."""
    out = tmp_path_factory.mktemp("matrix")
    ids = [r.object_id for r in open_dataset(dataset).records(hand="allegro") if r.pregrasp is not None]
    clusters = out / "clusters.json"
    clusters.write_text(json.dumps({oid: i for i, oid in enumerate(ids)}))
    experts = [parse_expert(e) for e in EXPERTS]
    report = evaluate_experts(dataset, run_config(), experts, out, clusters=clusters, registry=InterruptingRegistry())
    return report, out, {oid: i for i, oid in enumerate(ids)}


def test_the_matrix_holds_every_object_and_expert(full):
    report, out, clusters = full
    m = load_matrix(matrix_path(out, "allegro", "sapien"))
    assert report.path == matrix_path(out, "allegro", "sapien") and m.experts == ("scripted", "low")
    assert len(m.object_ids) == 2 and m.complete and (m.episodes == 2).all()
    assert m.clusters == tuple(clusters[oid] for oid in m.object_ids) and m.baseline == "scripted"
    assert m.expert_names == ("scripted", "scripted") and m.expert_settings[1]["lift"] == 0.05
    assert m.expert_settings[0] == load_registry().settings("expert", "scripted")  # the full settings it ran with
    raw = json.loads(report.path.read_text())
    assert raw["run"]["env"]["randomization"]["mass"] is True and report.evaluated == 4 and report.reused == 0
    for oid in m.object_ids:  # cells hold what the reader counts: one end reason per episode
        for label in m.experts:
            cell = raw["cells"][oid][label]
            assert len(cell["end_reasons"]) == cell["episodes"] == 2
            assert cell["paper"] == cell["end_reasons"].count("success")
    low = m.successes["peers"][:, m.column("low")]
    assert (low == 0).all()  # 5 cm up meets neither protocol
    assert max(max(c["max_rise"]) for c in (raw["cells"][o]["low"] for o in m.object_ids)) < 0.15


def test_randomization_makes_the_episodes_of_a_cell_differ(full):
    report, _, _ = full
    cells = json.loads(report.path.read_text())["cells"]
    rises = [tuple(c["max_rise"]) for obj in cells.values() for c in obj.values()]
    assert any(r[0] != r[1] for r in rises)  # 2 envs of one object and expert: other start pose, mass, friction


def test_the_oracle_is_the_best_expert_per_object(full):
    report, _, _ = full
    m = report.matrix
    for protocol in ("paper", "peers"):
        rates, (best, which) = m.rates(protocol), m.oracle(protocol)
        raw = json.loads(report.path.read_text())["cells"]
        for i, oid in enumerate(m.object_ids):  # the oracle from the raw cells, by hand
            by_hand = max(raw[oid][label][protocol] / raw[oid][label]["episodes"] for label in m.experts)
            assert best[i] == pytest.approx(by_hand) and rates[i, which[i]] == best[i]
            assert all(best[i] >= rates[i, j] for j in range(len(m.experts)))
        table = split_rates(m, protocol)
        assert table["oracle"] == pytest.approx(best.mean())
        assert all(table["oracle"] >= table[label] - 1e-12 for label in m.experts)
    text = expert_table(m, "paper")
    assert "| scripted (baseline) |" in text and "| low |" in text and "| oracle (best expert per object) |" in text


def test_a_resumed_run_counts_the_cells_other_code_ran(full, dataset, tmp_path):
    """Reused cells whose code stamp is not this code's are counted and named in the summary (not rerun)."""
    report, _, _ = full
    raw = json.loads(report.path.read_text())
    oid = next(iter(raw["cells"]))
    label = next(iter(raw["cells"][oid]))
    raw["cells"][oid][label]["code"] = "0123456789ab"
    copy = tmp_path / report.path.name
    copy.write_text(json.dumps(raw))
    experts = [parse_expert(e) for e in EXPERTS]
    again = evaluate_experts(dataset, run_config(), experts, tmp_path, registry=InterruptingRegistry())
    assert again.evaluated == 0 and again.reused_other_code == 1
    assert "(1 run by other code than this" in again.summary()
    assert "run by other code" not in report.summary()


def test_a_killed_run_resumes_with_the_missing_cells(full, dataset, tmp_path):
    report, _, _ = full
    experts = [parse_expert(e) for e in EXPERTS]
    with pytest.raises(KeyboardInterrupt):  # killed in the third cell (2 simulators per cell: rest pose, episodes)
        evaluate_experts(dataset, run_config(), experts, tmp_path, registry=InterruptingRegistry(stop_at=5))
    partial = load_matrix(matrix_path(tmp_path, "allegro", "sapien"))
    assert int((partial.episodes > 0).sum()) == 2  # the two finished cells were written
    registry = InterruptingRegistry()
    again = evaluate_experts(dataset, run_config(), experts, tmp_path, registry=registry)
    assert (again.reused, again.evaluated, registry.sims) == (2, 2, 4)
    done, ref = (json.loads(p.read_text())["cells"] for p in (again.path, report.path))
    for oid in ref:  # same episodes as the uninterrupted run, cell by cell
        for label in ref[oid]:
            for key in ("end_reasons", "max_rise", "steps"):
                assert done[oid][label][key] == ref[oid][label][key], (oid, label, key)
    assert evaluate_experts(dataset, run_config(), experts, tmp_path, registry=InterruptingRegistry(refuse=True))


@pytest.mark.slow
def test_workers_give_the_same_cells(full, dataset, tmp_path):
    """Two local worker processes (ges_core.executors) write the baseline cells the in-process run wrote."""
    report, _, _ = full
    pooled = evaluate_experts(dataset, run_config(), [], tmp_path, fanout=Fanout(workers=2))
    done, ref = (json.loads(p.read_text())["cells"] for p in (pooled.path, report.path))
    assert set(done) == set(ref) and all(set(cells) == {"scripted"} for cells in done.values())
    for oid in ref:
        for key in ("end_reasons", "max_rise", "steps"):
            assert done[oid]["scripted"][key] == ref[oid]["scripted"][key], (oid, key)


def test_other_settings_under_a_stored_label_or_run_are_refused(full, dataset):
    _, out, _ = full
    refuse = InterruptingRegistry(refuse=True)
    with pytest.raises(ConfigError, match=r"expert column 'low' of .* other settings \(settings.lift: 0.05 -> 0.1\)"):
        evaluate_experts(dataset, run_config(), [parse_expert("low=scripted:lift=0.1")], out, registry=refuse)
    with pytest.raises(ConfigError, match=r"written with other settings \(envs: 2 -> 3\)"):
        evaluate_experts(dataset, run_config(envs=3), [], out, registry=refuse)
    with pytest.raises(ConfigError, match=r"labels \['a'\] are given twice"):
        evaluate_experts(dataset, run_config(), [parse_expert("a=scripted"), parse_expert("a=scripted")], out)
    with pytest.raises(UnknownNameError, match=r"unknown expert 'scriptd'"):
        evaluate_experts(dataset, run_config(), [parse_expert("scriptd")], out, registry=refuse)


def test_a_matrix_from_before_the_wrist_matrix_is_reused_only_with_the_rotation_vector(full, dataset, tmp_path):
    """A matrix written before ``env.wrist_rotation`` existed lacks the key: its cells ran the rotation vector. A run
    that asks for it reuses every cell; today's default (the matrix form) is refused naming the setting."""
    report, _, _ = full
    raw = json.loads(report.path.read_text())
    assert raw["run"]["env"]["wrist_rotation"] == "matrix"  # today's default is stored
    del raw["run"]["env"]["wrist_rotation"]  # as the code before the setting wrote it
    (tmp_path / report.path.name).write_text(json.dumps(raw))
    experts = [parse_expert(e) for e in EXPERTS]
    env = {"randomization": RANDOMIZED}
    with pytest.raises(ConfigError, match=r"written with other settings \(env.wrist_rotation: .*matrix"):
        evaluate_experts(dataset, run_config(), experts, tmp_path, registry=InterruptingRegistry(refuse=True))
    rotvec = run_config(env=env | {"wrist_rotation": "rotvec"})
    again = evaluate_experts(dataset, rotvec, experts, tmp_path, registry=InterruptingRegistry(refuse=True))
    assert again.evaluated == 0 and again.reused == sum(len(c) for c in raw["cells"].values())


def test_a_matrix_left_without_cells_is_started_over(dataset, tmp_path):
    """A run that fails before its first cell (here: every simulator build raises) leaves the matrix with its
    objects and no cell; a rerun with other settings (envs 3, another column) then starts it over instead of
    refusing settings nothing was evaluated with. A matrix holding one cell is still refused."""
    experts = [parse_expert("low=scripted:lift=0.1")]
    with pytest.raises(AssertionError, match="should not build a simulator"):
        evaluate_experts(dataset, run_config(), experts, tmp_path, registry=InterruptingRegistry(refuse=True))
    path = matrix_path(tmp_path, "allegro", "sapien")
    left = json.loads(path.read_text())
    assert left["objects"] and not any(left["cells"].values()) and left["run"]["envs"] == 2
    with pytest.raises(KeyboardInterrupt):  # one cell (the rest pose's build, the episodes'), killed at the next
        evaluate_experts(dataset, run_config(envs=3), [], tmp_path, registry=InterruptingRegistry(stop_at=3))
    kept = json.loads(path.read_text())
    assert kept["run"]["envs"] == 3 and list(kept["experts"]) == ["scripted"]
    assert sum(len(cells) for cells in kept["cells"].values()) == 1
    with pytest.raises(ConfigError, match=r"written with other settings \(envs: 3 -> 2\)"):
        evaluate_experts(dataset, run_config(), [], tmp_path, registry=InterruptingRegistry(refuse=True))


def test_a_column_stored_before_its_expert_gained_a_setting_is_the_same_column(full, dataset, tmp_path):
    """A matrix written before the scripted expert had palm_shift lacks it: its columns ran the default (0), so they
    are reused and pool with new ones; a stored column that ran another value is still refused."""
    report, _, _ = full
    raw = json.loads(report.path.read_text())
    for column in raw["experts"].values():
        assert column["settings"].pop("palm_shift") == 0.0  # as written before the setting existed
    old = tmp_path / "old" / report.path.name
    old.parent.mkdir()
    old.write_text(json.dumps(raw))
    pooled = pool_matrices([load_matrix(report.path), load_matrix(old)])
    assert (pooled.episodes == 4).all()
    experts = [parse_expert(e) for e in EXPERTS]
    again = evaluate_experts(dataset, run_config(), experts, old.parent, registry=InterruptingRegistry(refuse=True))
    assert (again.evaluated, again.reused) == (0, 4)
    assert json.loads(old.read_text())["experts"]["low"]["settings"]["palm_shift"] == 0.0  # completed in the file
    raw["experts"]["low"]["settings"]["palm_shift"] = 0.01
    old.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match=r"column 'low' .* other settings \(settings.palm_shift: 0.01 -> 0.0\)"):
        evaluate_experts(dataset, run_config(), experts, old.parent, registry=InterruptingRegistry(refuse=True))
    with pytest.raises(ConfigError, match=r"expert column 'low' ran other settings in matrix 2"):
        pool_matrices([load_matrix(report.path), load_matrix(old)])


def test_a_bad_clusters_file_is_a_clear_error(full, dataset, tmp_path):
    _, out, _ = full
    bad = tmp_path / "clusters.json"
    bad.write_text(json.dumps({"procedural/cube/000": "big"}))
    with pytest.raises(AssetError, match=r"neither a clusters file of ges cluster nor a JSON object mapping"):
        evaluate_experts(dataset, run_config(), [], out, clusters=bad, registry=InterruptingRegistry(refuse=True))


def test_cli_prints_both_tables_from_the_stored_matrix(full, dataset, capsys):
    _, out, _ = full
    args = ["eval-experts", str(dataset), "--hand", "allegro", "--sim", "sapien", "--episodes", "2",
            "--select", "any", "--out", str(out), "--no-progress"]  # fmt: skip
    assert main([*args, "--expert", "low=scripted:lift=0.05"]) == 0
    text = capsys.readouterr().out
    assert "success (paper:" in text and "success (peers:" in text and "0 cell(s) evaluated, 4 reused" in text
    m = load_matrix(matrix_path(out, "allegro", "sapien"))
    k, n = int(m.successes["paper"][:, 0].sum()), int(m.episodes[:, 0].sum())
    baseline = next(line for line in text.splitlines() if line.startswith("| scripted (baseline) |"))
    assert baseline.endswith(f"| {100 * k / n:.1f} % ({k}/{n}) |")  # the 'all' column of the paper table
    against = text.split("against the baseline:", 1)[1]
    low = next(line for line in against.splitlines() if line.startswith("| low |"))
    j = m.column("low")
    points = 100 * (m.successes["paper"][:, j].sum() / m.episodes[:, j].sum() - k / n)
    assert low.split("|")[-2].strip().startswith(f"{points:+.1f} [")
    notes = [line for line in text.splitlines() if line.startswith("note: expert ")]
    cells = json.loads(matrix_path(out, "allegro", "sapien").read_text())["cells"]
    late = sum(cells[oid]["low"]["end_reasons"].count("timeout") for oid in m.object_ids)
    # 'low' carries 5 cm up and holds there: lifted, never at 0.2 m, out of steps; the baseline's end otherwise
    assert late == m.episodes[:, j].sum() and len(notes) == 1
    assert notes[0].startswith(f"note: expert 'low': {late} of {late} episodes (100 %) ran out of the episode's 200 ")
    assert main([*args, "--expert", "x=nosuch"]) == 1
    assert "unknown expert 'nosuch'" in capsys.readouterr().err


def test_late_columns_names_the_columns_that_run_out_of_steps(tmp_path):
    """The note's rule on its own: a column is named from LATE_SHARE of its episodes ending 'timeout' on."""
    from ges_core.experts.table import LATE_SHARE, late_columns

    def cell(reasons):
        return {"episodes": len(reasons), "paper": reasons.count("success"), "peers": 0, "end_reasons": reasons}

    n = 100  # one object, 100 episodes per column: 'edge' has exactly LATE_SHARE of them late, 'under' one fewer
    k = round(LATE_SHARE * n)
    reasons = {
        "edge": ["timeout"] * k + ["success"] * (n - k),
        "under": ["timeout"] * (k - 1) + ["dropped"] * (n - k + 1),
    }
    data = {"format": "ges.expert_matrix", "version": 1, "experts": {c: {"name": "s", "settings": {}} for c in reasons},
            "objects": {"o": {"split": "train", "category": "c"}},
            "cells": {"o": {c: cell(r) for c, r in reasons.items()}}}  # fmt: skip
    path = tmp_path / "m.json"
    path.write_text(json.dumps(data))
    m = load_matrix(path)
    lines = late_columns(data["cells"], m, episode_length=150)
    assert len(lines) == 1 and lines[0].startswith(f"expert 'edge': {k} of {n} episodes") and "150 control" in lines[0]
    assert late_columns(data["cells"], m, episode_length=150, share=1.0) == []
    other = late_columns({"o2": data["cells"]["o"]}, m, episode_length=150)  # cells of objects not in the view
    assert other == []
    # the late episodes' highest rise tells a plan that needs more steps (held about the lift height) from a policy
    # that throws the object: the median of the late episodes only (the successes' rises do not count)
    cells = data["cells"]["o"]
    cells["edge"]["max_rise"] = [0.45] * k + [0.22] * (n - k)
    thrown = late_columns(data["cells"], m, episode_length=150, lift_height=0.2)
    assert len(thrown) == 1 and "median 0.45 m up against the 0.2 m lift" in thrown[0]
    assert "longer episode will not help" in thrown[0] and "-o env.episode_length" not in thrown[0]
    cells["edge"]["max_rise"] = [0.29] * k + [0.9] * (n - k)  # under OVERSHOOT lift heights: the plan may not fit
    held = late_columns(data["cells"], m, episode_length=150, lift_height=0.2)
    assert len(held) == 1 and "-o env.episode_length=N" in held[0]
    assert late_columns(data["cells"], m, episode_length=150) == lines  # no lift height: the first advice


def test_the_reader_refuses_other_files(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"format": "ges.baseline_results"}))
    with pytest.raises(AssetError, match=r"is not a success matrix"):
        load_matrix(path)


def test_an_unevaluated_cell_is_nan_and_the_oracle_skips_it(tmp_path):
    data = {"format": "ges.expert_matrix", "version": 1, "experts": {"a": {"name": "s", "settings": {}},
            "b": {"name": "s", "settings": {}}}, "objects": {"o": {"split": "train", "category": "c"}},
            "cells": {"o": {"b": {"episodes": 4, "paper": 1, "peers": 3}}}}  # fmt: skip
    path = tmp_path / "m.json"
    path.write_text(json.dumps(data))
    m = load_matrix(path)
    assert np.isnan(m.rates("paper")[0, 0]) and m.rates("paper")[0, 1] == 0.25 and not m.complete
    best, which = m.oracle("peers")
    assert (best[0], which[0]) == (0.75, 1)


def test_a_column_names_the_content_of_the_files_its_settings_name(tmp_path):
    """A retrained checkpoint at the same path is another column identity (stored results are not reused for it)."""
    from ges_core.experts.evaluate import column_identity

    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(b"weights 1")

    class Settings:  # the registry's settings look-up only
        def settings(self, kind, name):
            return {"checkpoint": str(checkpoint), "deterministic": True}

    first = column_identity(Settings(), parse_expert("ppo"))
    assert first["settings"]["checkpoint"] == str(checkpoint) and set(first["files"]) == {"checkpoint"}
    checkpoint.write_bytes(b"weights 2")
    assert column_identity(Settings(), parse_expert("ppo"))["files"] != first["files"]
    assert "files" not in column_identity(load_registry(), parse_expert("scripted"))
