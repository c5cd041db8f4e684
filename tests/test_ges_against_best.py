"""GES against the best single expert of each split (``ges_core.ges_eval.against_best``): the best expert is the
split's, the difference is the pooled rates' (numpy on the same counts), and the verdict follows the interval."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.experts.matrix import SuccessMatrix
from ges_core.ges_eval.against_best import ges_against_best, ges_against_best_table, ges_between
from ges_core.ges_eval.table import GesRow

SPLITS = ["train"] * 30 + ["unseen_object"] * 12


def _matrix(rng) -> SuccessMatrix:
    """Three columns over 42 objects of 2 splits, 4 episodes each: on train ``b`` wins most, on unseen objects
    ``a``; ``scripted`` is the baseline column, never the best."""
    n = len(SPLITS)
    wins = np.zeros((n, 3), dtype=np.int64)
    train = np.array([s == "train" for s in SPLITS])
    wins[:, 0] = np.where(train, rng.integers(0, 3, n), rng.integers(3, 5, n))  # a
    wins[:, 1] = np.where(train, rng.integers(3, 5, n), rng.integers(0, 2, n))  # b
    wins[:, 2] = rng.integers(0, 2, n)  # scripted
    return SuccessMatrix(
        object_ids=tuple(f"o/{i:03d}" for i in range(n)), splits=tuple(SPLITS), categories=("c",) * n,
        clusters=(None,) * n, experts=("a", "b", "scripted"), expert_names=("ppo", "ppo", "scripted"),
        expert_settings=({}, {}, {}), episodes=np.full((n, 3), 4, dtype=np.int64),
        successes={"paper": wins, "peers": wins.copy()}, baseline="scripted",
    )  # fmt: skip


def _row(label, matrix, picked) -> GesRow:
    n = len(matrix.object_ids)
    wins = {p: matrix.successes[p][np.arange(n), picked] for p in matrix.successes}
    return GesRow(label, wins, matrix.episodes[np.arange(n), picked], np.asarray(picked))


def test_ges_against_the_best_expert_of_each_split() -> None:
    rng = np.random.default_rng(0)
    m = _matrix(rng)
    train = np.array([s == "train" for s in SPLITS])
    perfect = _row("perfect", m, np.where(train, 1, 0))  # b on train, a on unseen objects: the best of each
    only_b = _row("only_b", m, np.ones(len(SPLITS), dtype=np.int64))
    per_object_best = _row("oracle", m, m.successes["paper"][:, :2].argmax(axis=1))
    diffs = ges_against_best(m, [perfect, only_b, per_object_best], ["a", "b"], resamples=2000)
    by = {(d.expert, d.split): (best, d) for best, d in diffs}

    assert by[("GES (perfect)", "train")][0] == "b" and by[("GES (perfect)", "unseen_object")][0] == "a"
    for split in ("train", "unseen_object"):  # the gate that picks the split's best expert everywhere equals it
        best, d = by[("GES (perfect)", split)]
        assert (d.points, d.low, d.high, d.better, d.worse) == (0.0, 0.0, 0.0, 0, 0)
        assert d.verdict == "not distinguishable"
    best, d = by[("GES (only_b)", "unseen_object")]  # b where a is much better: below, on 12 objects
    rows = np.array([s == "unseen_object" for s in SPLITS])
    expected = 100 * (m.successes["paper"][rows, 1].sum() - m.successes["paper"][rows, 0].sum()) / (4 * rows.sum())
    assert np.isclose(d.points, expected) and d.verdict == "below" and d.objects == 12
    best, d = by[("GES (oracle)", None)]  # per object best: never down, up wherever the other column won
    assert d.worse == 0 and d.better > 10 and d.verdict == "above" and d.low > 0
    text = ges_against_best_table(diffs)
    assert "| gate |" in text and "| GES (only_b) |" in text and "vs a (" in text
    assert " below |" in text and "above** |" in text


def test_one_gate_against_another_is_the_difference_of_their_episodes() -> None:
    m = _matrix(np.random.default_rng(1))
    n = len(SPLITS)
    only_a, only_b = _row("only_a", m, np.zeros(n, dtype=np.int64)), _row("only_b", m, np.ones(n, dtype=np.int64))
    diffs = ges_between(m, [only_a, only_b], [("only_b", "only_a")], resamples=1000)
    by = {(d.expert, d.split): (versus, d) for versus, d in diffs}
    for split, rows in (("train", np.array([s == "train" for s in SPLITS])), (None, np.ones(n, dtype=bool))):
        versus, d = by[("GES (only_b)", split)]
        expected = 100 * (m.successes["paper"][rows, 1].sum() - m.successes["paper"][rows, 0].sum()) / (4 * rows.sum())
        assert versus == "only_a" and np.isclose(d.points, expected) and d.objects == rows.sum()
    assert by[("GES (only_b)", "train")][1].verdict == "above"  # b wins most on train by construction
    assert by[("GES (only_b)", "unseen_object")][1].verdict == "below"
    assert "vs only_a (" in ges_against_best_table(diffs, title="GES of one gate against another's")
    with pytest.raises(KeyError, match="no GES row 'nope'"):
        ges_between(m, [only_a], [("nope", "only_a")])
