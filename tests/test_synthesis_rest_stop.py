"""The resting check in the attempt loop: run once per object and engine, and an object that does not stay at rest
on its own in an engine (``unstable_rest``) ends the placement search where no placement can change the outcome."""

from __future__ import annotations

import pytest

from ges_core.dataset import open_dataset
from ges_core.synthesis import SynthesisConfig, run_synthesis

OID = "procedural/cube/000"


def _doubles(monkeypatch, *, holds: set[int], rest: dict[str, str]):
    """Test doubles: the nominal trial of the i-th placement judged in an engine holds when i is in ``holds``, else
    it drops; the perturbation trials hold; ``rest`` maps an engine to the reason its rest check gives. Returns the
    grasps refinement was given, in order."""
    from ges_core.errors import SynthesisError
    from ges_core.synthesis.physics.robust import TrialResult
    from ges_core.synthesis.run import worker
    from ges_core.synthesis.types import ValidationResult

    given, judged = [], {"sapien": 0, "pybullet": 0}
    real_refine = worker.refine_grasp

    def refine(sim, hand, obj, grasp, *args, **kwargs):
        given.append(grasp)
        return real_refine(sim, hand, obj, grasp, *args, **kwargs)

    def validate(sim, *args, **kwargs):
        judged[sim.name] += 1
        ok = judged[sim.name] - 1 in holds
        return ValidationResult(ok, "success" if ok else "dropped", {}, 0.01)

    def trial(scenes, asset, grasp, pre, config, perturbation, limits):
        return TrialResult(perturbation.name, True, "success", 0.01)

    def rest_problem(self, hand, name, asset):
        reason = rest.get(name)
        return None if reason is None else SynthesisError("rolls", reason=reason)

    monkeypatch.setattr(worker, "refine_grasp", refine)
    monkeypatch.setattr(worker, "validate_grasp", validate)
    monkeypatch.setattr(worker, "run_trial", trial)
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
    """The refining engine's rest check fails (unstable_rest): no placement is refined, one attempt is recorded."""
    given = _doubles(monkeypatch, holds=set(), rest={"sapien": "unstable_rest"})
    record = _run(tmp_path, ["sapien"])
    assert given == [] and [a.refinement for a in record.attempts] == ["unstable_rest"]
    assert record.steps["refinement"].reason == "unstable_rest" and record.attempt is None
    assert record.errors["refinement"] == "rolls"


@pytest.mark.sim
def test_the_rest_check_runs_once_per_object_and_counts_in_refinement(tmp_path, monkeypatch) -> None:
    """Three placements refined, the real rest check run once in the refining engine (made 0.3 s slower), every
    refinement told to skip its own (``rest_steps=0``), and the check's time counted once in the refinement step."""
    import time

    from ges_core.synthesis.run import worker

    checks, settings, refined, checked = [], [], [], []
    real_check, real_refine = worker.check_rest, worker.refine_grasp

    def slow_check(sim, *args, **kwargs):
        checks.append(sim.name)
        start = time.perf_counter()
        time.sleep(0.3)
        real_check(sim, *args, **kwargs)
        checked.append(time.perf_counter() - start)

    def refine(sim, hand, obj, grasp, config, **kwargs):
        settings.append(config.rest_steps)
        refined.append(real_refine(sim, hand, obj, grasp, config, **kwargs))
        return refined[-1]

    monkeypatch.setattr(worker, "check_rest", slow_check)
    monkeypatch.setattr(worker, "refine_grasp", refine)
    monkeypatch.setattr(worker, "refine_verdict", lambda *args, **kwargs: "few_contacts")  # every placement fails
    library = {"sources": ["procedural"], "procedural_count": 1}
    config = SynthesisConfig.model_validate(
        {
            "library": library,
            "validate_sims": ["sapien"],
            "attempts": 3,
            "balanced_thumb": "never",
            "low_raise": "never",
        }
    )  # one set of contacts' three placements (the balanced thumb's pass would refine three more)
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    assert checks == ["sapien"] and settings == [0, 0, 0] and len(record.attempts) == 3
    expected = sum(r.seconds for r in refined) + checked[0]  # the check once, with every refinement
    assert record.steps["refinement"].seconds == pytest.approx(expected, abs=0.01)
