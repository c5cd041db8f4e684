"""benchmarks/ges_pooled.py: runs of the same GES pooled by gate label, whatever order each run lists its gates in."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.experts.matrix import PROTOCOLS
from ges_core.ges_eval.table import GesRow

from conftest import benchmark_module


@pytest.fixture(scope="module")
def pooled():
    return benchmark_module("ges_pooled")


def _row(label: str, rng: np.random.Generator, n: int = 5) -> GesRow:
    episodes = rng.integers(0, 5, n)
    return GesRow(label, {p: rng.integers(0, episodes + 1) for p in PROTOCOLS}, episodes, rng.integers(0, 3, n))


def test_gates_are_matched_by_label_and_a_gate_not_every_run_holds_is_left_out(pooled) -> None:
    rng = np.random.default_rng(0)
    first = [_row(label, rng) for label in ("centroid", "curvenet", "curvenet-argmax", "pointnet2")]
    second = [_row(label, rng) for label in ("curvenet-argmax", "centroid", "curvenet")]  # other order, no pointnet2
    third = [_row(label, rng) for label in ("curvenet", "centroid", "pointnet2", "curvenet-argmax")]
    rows = pooled.pooled_rows([first, second, third])

    assert [r.label for r in rows] == ["centroid", "curvenet", "curvenet-argmax"]
    for row in rows:
        same = [next(r for r in run if r.label == row.label) for run in (first, second, third)]
        np.testing.assert_array_equal(row.episodes, same[0].episodes + same[1].episodes + same[2].episodes)
        for p in PROTOCOLS:
            np.testing.assert_array_equal(row.successes[p], sum(r.successes[p] for r in same))
        np.testing.assert_array_equal(row.picked, same[0].picked)


def test_runs_that_share_no_gate_are_refused_naming_them(pooled) -> None:
    with pytest.raises(SystemExit, match=r"share no gate: \[\['centroid'\], \['curvenet'\]\]"):
        pooled.common_gates([["centroid"], ["curvenet"]])
