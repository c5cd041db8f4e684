"""The in-run evaluation's figures (``ges_core.training.evaluation``): rates over objects and the comparison with
the starting policy, on hand-written rows (the simulator runs are in test_train_expert.py)."""

from __future__ import annotations

import json
import math

from ges_core.training.evaluation import EvaluationResult, describe_evaluation


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


def test_a_tie_with_the_best_is_not_a_new_best(tmp_path) -> None:
    """46/52 twice (a rate that does not round to itself): the second is not 'best so far' (the stored best is
    rounded to 4 digits; compared as stored). Runs GraspRunner._evaluate on a stand-in runner whose evaluator returns
    hand-written results (no simulator)."""
    from pathlib import Path
    from types import SimpleNamespace

    from ges_core.training.config import CurriculumConfig
    from ges_core.training.curriculum import Curriculum
    from ges_core.training.runner import GraspRunner

    rates = iter([(45, 52), (46, 52), (46, 52), (47, 52)])

    def evaluate(path, done):
        assert path.is_file()  # the weights were written for the expert to read
        wins, n = next(rates)
        per_object = {f"o{i}": [4, 0, 0] for i in range(13)}
        for i in range(wins):
            per_object[f"o{i % 13}"][1] += 1
        assert n == 52
        return EvaluationResult(done, per_object)

    (tmp_path / "checkpoints").mkdir()
    runner = SimpleNamespace(
        run_dir=tmp_path, save=lambda path: Path(path).write_bytes(b"weights"), curriculum=Curriculum(
            CurriculumConfig(stages=[3]), {3: [f"o{i}" for i in range(13)]}),
        evaluation={"last": None, "best": None, "best_iteration": None, "start": None},
        evaluator=SimpleNamespace(evaluate=evaluate, config=SimpleNamespace(envs=4)),
        logger=SimpleNamespace(writer=None), on_evaluation=None,
    )  # fmt: skip
    flags = []
    for done in (0, 200, 400, 600):
        GraspRunner._evaluate(runner, done)
        flags.append(runner._new_best)
    assert flags == [True, True, False, True] and runner.evaluation["best_iteration"] == 600
    rows = [json.loads(x) for x in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert [r["best"] for r in rows] == flags and not (tmp_path / "checkpoints" / "evaluating.pt").exists()
    assert rows[2]["vs_start"] == {"points": round(100 / 52, 2), "objects_up": 1, "objects_down": 0}
