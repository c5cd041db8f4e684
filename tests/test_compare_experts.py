"""Experts against the scripted baseline: seeds pooled, paired bootstrap intervals, ``ges compare-experts``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from ges_core.cli import main
from ges_core.errors import ConfigError
from ges_core.experts.compare import (
    compare_to_baseline,
    comparison_table,
    held_out_oracle,
    held_out_oracle_table,
    pool_matrices,
)
from ges_core.experts.matrix import load_matrix, write_matrix


def _matrix_file(path, wins, episodes=4, splits=None, labels=None, settings=None):
    """Objects o0..oN-1, expert columns (the first the scripted baseline) with ``wins`` successes of ``episodes``."""
    wins = np.asarray(wins)
    n, m = wins.shape
    splits = splits or ["train"] * n
    labels = labels or ["scripted", *[f"e{j}" for j in range(1, m)]]
    settings = settings or [{} for _ in labels]
    data = {
        "dataset": "runs/x/dataset",
        "run": {},
        "experts": {
            e: {"name": "scripted" if j == 0 else "ppo", "settings": settings[j]} for j, e in enumerate(labels)
        },
        "baseline": labels[0],
        "objects": {f"o{i}": {"split": splits[i], "category": "c", "cluster": 0} for i in range(n)},
        "cells": {
            f"o{i}": {
                e: {"episodes": episodes, "paper": int(wins[i, j]), "peers": int(min(episodes, wins[i, j] + 1))}
                for j, e in enumerate(labels)
            }
            for i in range(n)
        },
    }
    write_matrix(path, data)
    return path


def test_pooling_adds_the_episodes_and_successes_of_each_cell(tmp_path):
    rng = np.random.default_rng(3)
    a, b = rng.integers(0, 5, (7, 3)), rng.integers(0, 3, (7, 3))
    pooled = pool_matrices([load_matrix(_matrix_file(tmp_path / "a.json", a)),
                            load_matrix(_matrix_file(tmp_path / "b.json", b, episodes=2))])  # fmt: skip
    assert (pooled.episodes == 6).all()
    np.testing.assert_array_equal(pooled.successes["paper"], a + b)
    np.testing.assert_array_equal(pooled.rates("paper"), (a + b) / 6)


def test_pooling_refuses_runs_that_are_not_more_episodes_of_the_same_columns(tmp_path):
    base = load_matrix(_matrix_file(tmp_path / "a.json", [[1, 2], [3, 4]]))
    more_objects = load_matrix(_matrix_file(tmp_path / "b.json", [[1, 2], [3, 4], [0, 0]]))
    with pytest.raises(ConfigError, match=r"other objects.*only in 2: \['o2'\]"):
        pool_matrices([base, more_objects])
    other_columns = load_matrix(
        _matrix_file(tmp_path / "c.json", [[1, 2, 0], [3, 4, 1]], labels=["scripted", "res9", "e1"])
    )
    pooled = pool_matrices([base, other_columns])  # the columns both have, in the first one's order
    assert pooled.experts == ("scripted", "e1") and pooled.expert_names == ("scripted", "ppo")
    np.testing.assert_array_equal(pooled.successes["paper"], [[2, 2], [6, 5]])
    other_base = load_matrix(_matrix_file(tmp_path / "e.json", [[1, 2], [3, 4]], labels=["slow", "e1"]))
    with pytest.raises(ConfigError, match="baseline column slow, matrix 1 scripted"):
        pool_matrices([base, other_base])
    other_ckpt = load_matrix(_matrix_file(tmp_path / "d.json", [[1, 2], [3, 4]], settings=[{}, {"checkpoint": "x"}]))
    with pytest.raises(ConfigError, match="'e1' ran other settings"):
        pool_matrices([base, other_ckpt])
    with pytest.raises(ConfigError, match="no matrix"):
        pool_matrices([])


def test_an_expert_equal_to_the_baseline_is_not_distinguishable(tmp_path):
    wins = np.random.default_rng(0).integers(0, 5, 40)
    m = load_matrix(_matrix_file(tmp_path / "m.json", np.stack([wins, wins], axis=1)))
    (d,) = compare_to_baseline(m, splits=(None,))
    assert (d.points, d.low, d.high, d.better, d.worse) == (0.0, 0.0, 0.0, 0, 0)
    assert d.verdict == "not distinguishable" and d.objects == 40


def test_one_object_that_held_its_episode_is_too_few_for_a_verdict(tmp_path):
    m = load_matrix(_matrix_file(tmp_path / "m.json", [[0, 1]], episodes=1))
    (d,) = compare_to_baseline(m, splits=(None,))
    assert (d.points, d.low, d.high) == (100.0, 100.0, 100.0) and d.verdict == "too few objects"
    assert "too few objects" in comparison_table([d]) and "above" not in comparison_table([d])


def test_one_lucky_object_is_not_above_and_a_consistent_gain_is(tmp_path):
    base = np.full(40, 3)
    lucky = base.copy()
    lucky[0] = 4  # one episode more on one object of 40
    steady = np.minimum(base + 1, 4)  # one episode more on every object
    worse = base - 1
    m = load_matrix(_matrix_file(tmp_path / "m.json", np.stack([base, lucky, steady, worse], axis=1)))
    by = {d.expert: d for d in compare_to_baseline(m, splits=(None,))}
    assert by["e1"].points == pytest.approx(100 / 160) and by["e1"].verdict == "not distinguishable"
    assert (by["e1"].better, by["e1"].worse) == (1, 0)
    assert by["e2"].points == pytest.approx(25.0) and by["e2"].verdict == "above" and by["e2"].better == 40
    assert by["e3"].verdict == "below" and by["e3"].worse == 40
    text = comparison_table(list(by.values()))
    assert "**+25.0 [+25.0, +25.0] (40 up, 0 down) above**" in text and "below" in text


def test_the_interval_agrees_with_scipys_paired_bootstrap(tmp_path):
    rng = np.random.default_rng(11)
    n = 60
    base = rng.binomial(4, 0.8, n)
    expert = np.clip(base + rng.integers(-1, 3, n), 0, 4)
    m = load_matrix(_matrix_file(tmp_path / "m.json", np.stack([base, expert], axis=1)))
    (d,) = compare_to_baseline(m, splits=(None,), resamples=8000)

    def statistic(k_e, k_b, axis=-1):  # the same quantity: rate of pooled episodes, expert minus baseline, points
        return 100 * (k_e.mean(axis=axis) - k_b.mean(axis=axis)) / 4

    ref = stats.bootstrap((expert, base), statistic, paired=True, vectorized=True, n_resamples=8000,
                          method="percentile", random_state=np.random.default_rng(5))  # fmt: skip
    assert d.points == pytest.approx(statistic(expert, base))
    assert d.low == pytest.approx(ref.confidence_interval.low, abs=0.6)
    assert d.high == pytest.approx(ref.confidence_interval.high, abs=0.6)
    assert d.low < d.points < d.high


def test_per_split_rows_and_objects_without_episodes_left_out(tmp_path):
    path = _matrix_file(tmp_path / "m.json", [[4, 4], [0, 4], [2, 2]], splits=["train", "train", "unseen_object"])
    data = json.loads(path.read_text())
    del data["cells"]["o2"]["e1"]  # not evaluated (yet)
    write_matrix(path, data)
    rows = {d.split: d for d in compare_to_baseline(load_matrix(path))}
    assert rows["train"].objects == 2 and rows["train"].points == pytest.approx(50.0)
    assert (rows["train"].low, rows["train"].high) == (0.0, 100.0)
    assert rows["train"].verdict == "too few objects"  # a bootstrap over 2 objects says nothing
    assert rows["unseen_object"].objects == 0 and np.isnan(rows["unseen_object"].points)
    assert rows[None].objects == 2
    assert "| e1 | " in comparison_table(list(rows.values())) and "| - |" in comparison_table(list(rows.values()))


def test_cli_pools_seeds_and_writes_the_comparison(tmp_path, capsys):
    rng = np.random.default_rng(2)
    base = rng.binomial(4, 0.7, (30, 1))
    wins = np.concatenate([base, np.minimum(base + 1, 4)], axis=1)
    a = _matrix_file(tmp_path / "s0.json", wins)
    b = _matrix_file(tmp_path / "s1.json", wins)  # a second seed with the same counts
    out = tmp_path / "cmp.json"
    assert main(["compare-experts", str(a), str(b), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "2 matrix file(s) pooled: 480 episodes" in text
    assert "picked on the first matrix, scored on the others" in text
    assert "| e1 |" in text and "above" in text
    rows = json.loads(out.read_text())["rows"]
    assert {r["split"] for r in rows} == {"train", "unseen_object", "unseen_category", "all"}
    train = next(r for r in rows if r["split"] == "train")
    assert train["verdict"] == "above" and train["objects"] == 30
    held = {r["split"]: r for r in json.loads(out.read_text())["held_out_oracle"]}
    assert held["all"]["held_out"] == held["all"]["same"] == held["all"]["best_single"]  # e1 best everywhere
    three = np.concatenate([wins, base], axis=1)  # e2 = the baseline again
    c, d = _matrix_file(tmp_path / "c.json", three), _matrix_file(tmp_path / "d.json", three)
    assert main(["compare-experts", str(c), str(d), "--experts", "e2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| e2 |" in text and "| e1 |" not in text  # only the chosen column beside the baseline
    held = {r["split"]: r for r in json.loads(out.read_text())["held_out_oracle"]}
    assert held["all"]["best_label"] == "e2"  # the oracle picks among exactly the chosen columns
    assert main(["compare-experts", str(c), "--experts", "nosuch"]) == 1
    assert "no expert column 'nosuch'" in capsys.readouterr().err
    assert main(["compare-experts", str(a), str(_matrix_file(tmp_path / "x.json", wins[:5]))]) == 1
    assert "other objects" in capsys.readouterr().err


def test_the_held_out_oracle_scores_run_1s_picks_on_run_2(tmp_path):
    rng = np.random.default_rng(7)
    # two columns of equal true skill: each run's oracle gains on noise alone
    a = rng.binomial(4, 0.7, (50, 2))
    b = rng.binomial(4, 0.7, (50, 2))
    ma = load_matrix(_matrix_file(tmp_path / "a.json", a))
    mb = load_matrix(_matrix_file(tmp_path / "b.json", b))
    (h,) = held_out_oracle(ma, mb, splits=(None,))
    pick = a.argmax(axis=1)  # ties to the first column, as SuccessMatrix.oracle
    assert h.objects == 50
    assert h.same == pytest.approx(a.max(axis=1).mean() / 4)
    assert h.held_out == pytest.approx(b[np.arange(50), pick].mean() / 4)
    assert h.other == pytest.approx(b.max(axis=1).mean() / 4)
    assert h.best_single == pytest.approx(b.mean(axis=0).max() / 4)
    assert h.same > max(a.mean(axis=0)) / 4  # the same-episode oracle is above both equal columns
    (same_run,) = held_out_oracle(ma, ma, splits=(None,))
    assert same_run.held_out == same_run.same == same_run.other  # scored on its own episodes: the oracle row
    text = held_out_oracle_table([h])
    row = f"| all | 50 | {100 * h.same:.1f} % | {100 * h.held_out:.1f} % | {100 * h.other:.1f} % |"
    assert row in text and "picked on the first matrix, scored on the others" in text
    named = held_out_oracle_table([h], picked="seeds 0+1", scored="seed 2")
    assert "| oracle of seeds 0+1 | picked on seeds 0+1, scored on seed 2 | oracle of seed 2 |" in named


def test_the_held_out_oracle_keeps_a_real_difference(tmp_path):
    # column 1 is better on the first half of the objects, column 0 on the second, in both runs
    wins = np.array([[0, 4]] * 20 + [[4, 0]] * 20)
    (h,) = held_out_oracle(load_matrix(_matrix_file(tmp_path / "a.json", wins)),
                           load_matrix(_matrix_file(tmp_path / "b.json", wins)), splits=(None,))  # fmt: skip
    assert h.held_out == 1.0 and h.best_single == 0.5
