"""The in-run evaluation's figures (``ges_core.training.evaluation``): rates over objects and the comparison with
the starting policy, on hand-written rows (the simulator runs are in test_train_expert.py)."""

from __future__ import annotations

import math

from ges_core.training.evaluation import EvaluationResult
from ges_core.training.runner import describe_evaluation


def test_rates_and_the_comparison_with_the_start() -> None:
    start = {"a": [4, 2, 3], "b": [4, 4, 4], "c": [4, 1, 1]}
    now = EvaluationResult(200, {"a": [4, 4, 4], "b": [4, 3, 4], "c": [4, 1, 2], "d": [4, 0, 0]})
    assert now.rate() == 8 / 16 and now.rate(["a", "b"]) == 7 / 8 and now.rate(["a"], "peers") == 1.0
    assert now.episodes(["a", "d"]) == 8 and math.isnan(now.rate(["zzz"]))
    # on the objects both ran (d is new): 8/12 now against 7/12 at the start; a up, b down, c level
    assert now.against(start) == {"points": round(100 / 12, 2), "objects_up": 1, "objects_down": 1}
    row = {**now.to_row(), "stage": 3, "stage_success_paper": 0.5, "best": True, "vs_start": now.against(start)}
    line = describe_evaluation(row, 4, 4)
    assert line.startswith("iteration 200: evaluation 50.0 % (paper), 62.5 % (peers) over 4 object(s) x 4 ")
    assert "against the start +8.3 points (1 object(s) up, 1 down)" in line and line.endswith("(best so far)")
