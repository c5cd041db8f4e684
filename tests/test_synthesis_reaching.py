"""A pair whose best-fitting wrist placement misses its contacts tries the ranked placements that reach them."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.dataset import open_dataset
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.worker import _reaching
from ges_core.synthesis.types import Grasp

OID = "procedural/box/000"


def _grasp(reached: bool, label: int) -> Grasp:
    return Grasp(
        hand="allegro", wrist_pose=np.array([0, 0, label, 1, 0, 0, 0.0]), q=np.zeros(16), meta={"reached": reached}
    )


def _labels(grasps: list[Grasp]) -> list[int]:
    return [int(g.wrist_pose[2]) for g in grasps]


def test_an_unreached_best_gives_way_to_the_placements_that_reach():
    assert _labels(_reaching([_grasp(False, 0), _grasp(True, 1), _grasp(True, 2)])) == [1, 2]
    assert _labels(_reaching([_grasp(True, 0), _grasp(True, 1)])) == [0, 1]  # a best that reaches stays first
    assert _labels(_reaching([_grasp(False, 0)])) == [0]  # nothing reaches: the best, as before (unreachable)
    assert _labels(_reaching([_grasp(False, 0), _grasp(False, 1)])) == [0, 1]


def _run(tmp_path, monkeypatch, unreached: int) -> tuple[object, list, list]:
    """The pipeline on :data:`OID` with the Allegro, the first ``unreached`` ranked placements of each retargeting
    marked as missing their contacts; returns the record, the ranked placements and the placements refined."""
    from ges_core.synthesis.retarget.retargeter import GraspRetargeter
    from ges_core.synthesis.run import worker

    ranked, tried = [], []
    real_ranked, real_attempt = GraspRetargeter.retarget_ranked, worker._attempt

    def missing(self, *args, **kwargs):
        out = real_ranked(self, *args, **kwargs)
        for grasps in out:
            for g in grasps[:unreached]:
                g.meta["reached"] = False
            ranked.append(list(grasps))
        return out

    def attempt(state, sims, hand, work, grasp, *args):
        tried.append(grasp)
        return real_attempt(state, sims, hand, work, grasp, *args)

    monkeypatch.setattr(GraspRetargeter, "retarget_ranked", missing)
    monkeypatch.setattr(worker, "_attempt", attempt)
    library = {"sources": ["procedural"], "procedural_count": 1}
    config = SynthesisConfig.model_validate(
        {"library": library, "attempts": 3, "validate_sims": [], "other_strategy": "never"}
        | {"balanced_thumb": "never", "low_raise": "never"}
    )
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    return record, ranked, tried


@pytest.mark.sim
def test_the_pipeline_refines_the_first_placement_that_reaches(tmp_path, monkeypatch):
    record, ranked, tried = _run(tmp_path / "one", monkeypatch, unreached=1)
    (placements,) = ranked
    assert len(placements) == 3
    assert record.steps["retargeting"].ok and record.steps["refinement"].ok
    assert tried[0] is placements[1]  # the missing best fit was never refined
    assert all(g is not placements[0] for g in tried)
    # the record's grasp is the refined second placement (refinement moves a placement by millimetres; placements
    # differ by at least 15 degrees or 2 cm)
    kept = np.asarray(record.grasp.wrist_pose)
    assert np.abs(kept - placements[1].wrist_pose).max() < np.abs(kept - placements[0].wrist_pose).max()
    # the record says the best fit was left out, where the pass's tries begin and by how much the fit missed
    (note,) = record.extra["unreached_best_fit"]
    assert note == {"before_attempt": 0, "residual": placements[0].meta["residual"]}


@pytest.mark.sim
def test_where_no_placement_reaches_the_pair_stops_at_unreachable(tmp_path, monkeypatch):
    record, ranked, tried = _run(tmp_path / "none", monkeypatch, unreached=3)
    assert len(ranked[0]) == 3 and tried == []
    assert record.steps["retargeting"].reason == "unreachable"
    assert record.steps["refinement"].reason == "skipped"
    assert "unreached_best_fit" not in record.extra  # the best fit was the one tried (and it missed)


def test_joined_passes_place_each_left_out_best_fit_before_its_own_pass_tries():
    """Both passes' notes survive whichever pass is kept, the second's index moved past the first's attempts."""
    from ges_core.dataset.record import AttemptVerdict
    from ges_core.synthesis.run.records import PairResult
    from ges_core.synthesis.run.worker import _joined

    def pass_(attempts: int, notes: tuple[dict, ...]) -> PairResult:
        verdicts = tuple(AttemptVerdict(refinement="ok", validation="ok") for _ in range(attempts))
        return PairResult(steps={}, attempts=verdicts, unreached_best=notes)

    first = pass_(3, ({"before_attempt": 0, "residual": 0.02},))
    second = pass_(2, ({"before_attempt": 0, "residual": 0.03},))
    for kept in (True, False):
        joined = _joined(first, second, kept)
        assert len(joined.attempts) == 5
        assert joined.unreached_best == (
            {"before_attempt": 0, "residual": 0.02},
            {"before_attempt": 3, "residual": 0.03},
        )
    assert _joined(pass_(3, ()), pass_(2, ()), True).unreached_best == ()
