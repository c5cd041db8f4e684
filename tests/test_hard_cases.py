"""ges hard-cases: the training objects whose best experts all stay under a threshold, from a success matrix."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from ges_core.cli import main
from ges_core.errors import ConfigError
from ges_core.experts.hard_cases import find_hard_cases
from ges_core.experts.matrix import load_matrix, write_matrix
from ges_core.training.config import load_train_config


def _matrix_file(path, wins, episodes=4, splits=None, baseline_col=0):
    """A matrix file with objects o0..oN-1 and experts e0..eM-1 (column ``baseline_col`` the baseline)."""
    wins = np.asarray(wins)
    n, m = wins.shape
    splits = splits or ["train"] * n
    labels = [f"e{j}" for j in range(m)]
    data = {
        "dataset": "runs/x/dataset",
        "run": {},
        "experts": {
            e: {"name": "scripted" if j == baseline_col else "ppo", "settings": {}} for j, e in enumerate(labels)
        },
        "baseline": labels[baseline_col] if baseline_col is not None else None,
        "objects": {f"o{i}": {"split": splits[i], "category": "c", "cluster": 0} for i in range(n)},
        "cells": {
            f"o{i}": {
                e: {"episodes": episodes, "paper": int(wins[i, j]), "peers": int(wins[i, j])}
                for j, e in enumerate(labels)
            }
            for i in range(n)
        },
    }
    write_matrix(path, data)
    return path


def test_an_object_is_hard_when_its_two_best_learned_experts_fail(tmp_path):
    # columns: e0 the baseline, e1..e3 learned; 4 episodes each
    wins = [[4, 1, 0, 3], [4, 1, 0, 1], [0, 0, 0, 0], [4, 2, 2, 0]]
    hard = find_hard_cases(load_matrix(_matrix_file(tmp_path / "m.json", wins)), threshold=0.5)
    assert hard.object_ids == ("o1", "o2")  # o0: 0.75; o3: 0.5 is not under 0.5; the baseline's 1.0 does not count
    assert hard.best["o0"] == (("e3", 0.75), ("e1", 0.25))
    assert hard.best["o3"] == (("e1", 0.5), ("e2", 0.5))  # a tie keeps column order
    with_base = find_hard_cases(load_matrix(tmp_path / "m.json"), threshold=0.5, with_baseline=True)
    assert with_base.object_ids == ("o2",)


def test_the_set_matches_a_brute_force_reading_on_random_matrices(tmp_path):
    rng = np.random.default_rng(0)
    for trial in range(20):
        wins = rng.integers(0, 5, size=(12, 4))
        splits = list(rng.choice(["train", "unseen_object"], size=12))
        m = load_matrix(_matrix_file(tmp_path / f"m{trial}.json", wins, splits=splits))
        t = float(rng.choice([0.25, 0.5, 0.75, 1.0]))
        got = find_hard_cases(m, t).object_ids
        rates = wins[:, 1:] / 4.0
        want = tuple(
            f"o{i}" for i in range(12) if splits[i] == "train" and sorted(rates[i])[-2] < t and rates[i].max() < t
        )
        assert got == want


def test_bad_requests_are_clear_errors(tmp_path):
    m = load_matrix(_matrix_file(tmp_path / "m.json", [[1, 2]]))
    with pytest.raises(ConfigError, match=r"\(0, 1\]"):
        find_hard_cases(m, 0.0)
    with pytest.raises(ConfigError, match="no 'unseen_object' object"):
        find_hard_cases(m, split="unseen_object")
    only_base = load_matrix(_matrix_file(tmp_path / "b.json", [[1]]))
    with pytest.raises(ConfigError, match="no expert column to count besides the baseline"):
        find_hard_cases(only_base)


def test_cli_prints_the_set_and_a_train_command_that_parses(tmp_path, capsys):
    path = _matrix_file(tmp_path / "m.json", [[4, 0, 1], [4, 4, 0]])
    out = tmp_path / "hard.json"
    assert main(["hard-cases", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1 of 2 train object(s) are hard" in text
    line = text.strip().splitlines()[-1].strip()
    argv = shlex.split(line)
    assert argv[:3] == ["ges", "train-expert", "runs/x/dataset"]
    assert "objects=[o0]" in argv and "curriculum.stages=[1, 2]" in argv
    assert json.loads(out.read_text())["objects"] == ["o0"]
    overrides = [argv[i + 1] for i, a in enumerate(argv) if a == "-o"]
    cfg = load_train_config("tiny", overrides=overrides)  # the printed overrides are what train-expert reads
    assert cfg.objects == ["o0"] and list(cfg.curriculum.stages) == [1, 2]


def test_cli_line_carries_the_experts_training_settings(tmp_path, capsys):
    """With the experts' run folders beside their checkpoints, the printed line trains the hard-case expert with
    their settings (here residual actions on refined grasps), not the tiny preset's."""
    import yaml

    run = tmp_path / "experts" / "e1run"
    (run / "checkpoints").mkdir(parents=True)
    trained = load_train_config("tiny", overrides=["action_mode=residual", "selection=refined", "cluster=1"])
    (run / "config.yaml").write_text(yaml.safe_dump(trained.model_dump(mode="json"), sort_keys=False))
    path = _matrix_file(tmp_path / "m.json", [[4, 0, 1], [4, 4, 0]])
    data = json.loads(path.read_text())
    data["experts"]["e1"]["settings"] = {"checkpoint": str(run / "checkpoints" / "last.pt")}
    write_matrix(path, data)
    assert main(["hard-cases", str(path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    argv = shlex.split(next(line for line in lines if line.strip().startswith("ges train-expert")))
    assert argv[argv.index("--config") + 1] == str(run / "config.yaml")
    overrides = [argv[i + 1] for i, a in enumerate(argv) if a == "-o"]
    cfg = load_train_config("tiny", path=argv[argv.index("--config") + 1], overrides=overrides)
    assert (cfg.action_mode, cfg.selection) == ("residual", "refined")
    assert cfg.objects == ["o0"] and list(cfg.curriculum.stages) == [1, 2]
    default = load_train_config("tiny", overrides=overrides)  # what the line gave before: the preset's settings
    assert (default.action_mode, default.selection) == ("absolute", "validated")


def test_cli_counts_only_the_chosen_columns(tmp_path, capsys):
    # o0: e1 fails, e2 holds; o1: both fail. Counting e1 alone makes o0 hard too.
    path = _matrix_file(tmp_path / "m.json", [[4, 0, 4], [4, 0, 1]])
    assert main(["hard-cases", str(path), "--out", str(tmp_path / "all.json")]) == 0
    assert json.loads((tmp_path / "all.json").read_text())["objects"] == ["o1"]
    assert main(["hard-cases", str(path), "--experts", "e1", "--out", str(tmp_path / "e1.json")]) == 0
    chosen = json.loads((tmp_path / "e1.json").read_text())
    assert chosen["objects"] == ["o0", "o1"] and chosen["experts"] == ["e1"]
    capsys.readouterr()
    assert main(["hard-cases", str(path), "--experts", "e9"]) == 1
    assert "no expert column 'e9'" in capsys.readouterr().err
