"""The attempt loop where the object does not stay at rest on its own in an engine (``unstable_rest``)."""

from __future__ import annotations

import pytest

from ges_core.dataset import open_dataset
from ges_core.synthesis import SynthesisConfig, run_synthesis

OID = "procedural/cube/000"


def _doubles(monkeypatch, *, holds: set[int], rest: dict[str, str]):
    """Test doubles: the nominal trial of the i-th placement judged in an engine holds when i is in ``holds``, else
    it drops; the perturbation trials hold; ``rest`` maps an engine to the reason its rest check gives (refinement's
    own check in the refining engine). Returns the grasps refinement was given, in order."""
    from ges_core.errors import SynthesisError
    from ges_core.synthesis.physics.robust import RobustResult, TrialResult
    from ges_core.synthesis.run import worker
    from ges_core.synthesis.types import ValidationResult

    given, judged = [], {"sapien": 0, "pybullet": 0}
    real_refine = worker.refine_grasp

    def refine(sim, hand, obj, grasp, *args, **kwargs):
        given.append(grasp)
        if rest.get(sim.name) == "unstable_rest":
            raise SynthesisError("does not stay at its resting pose", reason="unstable_rest")
        return real_refine(sim, hand, obj, grasp, *args, **kwargs)

    def validate(sim, *args, **kwargs):
        judged[sim.name] += 1
        ok = judged[sim.name] - 1 in holds
        return ValidationResult(ok, "success" if ok else "dropped", {}, 0.01)

    def robust_trials(sim, *args, **kwargs):
        return RobustResult((TrialResult("pose_1", True, "success", 0.01),), True)

    def rest_problem(self, hand, name, asset):
        reason = rest.get(name)
        return None if reason is None else SynthesisError("rolls", reason=reason)

    monkeypatch.setattr(worker, "refine_grasp", refine)
    monkeypatch.setattr(worker, "validate_grasp", validate)
    monkeypatch.setattr(worker, "robust_validate", robust_trials)
    monkeypatch.setattr(worker._Sims, "rest_problem", rest_problem)
    return given


def _run(tmp_path, sims) -> object:
    library = {"sources": ["procedural"], "procedural_count": 1}
    config = SynthesisConfig.model_validate({"library": library, "validate_sims": sims, "attempts": 6})
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    return record


@pytest.mark.sim
def test_the_loop_stops_at_the_first_hold_where_another_engine_cannot_rest_the_object(tmp_path, monkeypatch) -> None:
    """PyBullet rolls the object away on its own (unstable_rest): no placement can hold there, so the first
    placement that holds every trial in SAPIEN (the second; the first drops) ends the loop instead of the loop trying
    every placement and keeping that one anyway."""
    _doubles(monkeypatch, holds={1, 2}, rest={"pybullet": "unstable_rest"})
    record = _run(tmp_path, ["sapien", "pybullet"])
    judged = [a.validation for a in record.attempts if a.validation != "skipped"]  # the placements that refined
    assert judged == ["dropped", "ok"] and record.attempt == len(record.attempts) - 1 < 5 and record.robust
    assert record.validations["pybullet"].reason == "unstable_rest"


@pytest.mark.sim
def test_the_loop_stops_when_the_object_does_not_rest_in_the_refining_engine(tmp_path, monkeypatch) -> None:
    """Refinement's own rest check fails (unstable_rest): every placement would, so one attempt is tried."""
    given = _doubles(monkeypatch, holds=set(), rest={"sapien": "unstable_rest"})
    record = _run(tmp_path, ["sapien"])
    assert len(given) == 1 and [a.refinement for a in record.attempts] == ["unstable_rest"]
    assert record.steps["refinement"].reason == "unstable_rest" and record.attempt is None
