"""The other grasp strategy: contacts of a forced strategy, and the pipeline's second pass when none of the PCA
strategy's placements passes, or none holds every perturbation trial (``SynthesisConfig.other_strategy``)."""

from __future__ import annotations

import pytest

from ges_core.dataset import open_dataset
from ges_core.errors import ConfigError
from ges_core.objects.library import ObjectLibrary
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.contacts.generate import generate_contacts

OID = "procedural/can/000"  # upright and tall: PCA chooses the side grasp (horizontal)


@pytest.fixture(scope="module")
def can_cloud():
    return ObjectLibrary(sources=("procedural",), procedural_count=1).point_cloud(OID, 1024, seed=0)


def test_a_forced_strategy_is_the_only_one_tried(can_cloud) -> None:
    points, normals = can_cloud
    chosen = generate_contacts(points, normals, object_id=OID)
    forced = generate_contacts(points, normals, object_id=OID, strategy="vertical")
    assert chosen.strategy == "horizontal" and forced.strategy == "vertical"
    assert forced.contacts.meta["strategy_pca"] == "horizontal"  # what PCA chose, as without forcing
    assert forced.approach[2] < -0.99 and abs(chosen.approach[2]) < 0.1  # from above; from the side
    again = generate_contacts(points, normals, object_id=OID, strategy="horizontal")
    assert (again.contacts.positions == chosen.contacts.positions).all()  # forcing PCA's own choice changes nothing
    with pytest.raises(ConfigError, match="strategy must be"):
        generate_contacts(points, normals, object_id=OID, strategy="diagonal")


def _doubles(monkeypatch, *, fails: set[str], fragile: dict[str, int] | None = None) -> dict[str, list]:
    """Test doubles: refinement's verdict is ``table_contact`` for placements of a strategy in ``fails``; every
    validation holds; of four perturbation trials, a strategy in ``fragile`` fails that many (from the last), the
    others none. Returns the strategies generated and each refinement's seconds."""
    from ges_core.synthesis.physics.robust import RobustResult, TrialResult
    from ges_core.synthesis.run import worker
    from ges_core.synthesis.types import ValidationResult

    seen: dict[str, list] = {"strategies": [], "refined": [], "setup": []}
    real_generate, real_refine, real_verdict = worker.generate_contacts, worker.refine_grasp, worker.refine_verdict

    def generate(*args, **kwargs):
        result = real_generate(*args, **kwargs)
        seen["strategies"].append(result.strategy)
        return result

    def refine(*args, **kwargs):
        refined = real_refine(*args, **kwargs)
        seen["refined"].append(refined.seconds)
        return refined

    def verdict(*args, **kwargs):
        return "table_contact" if seen["strategies"][-1] in fails else real_verdict(*args, **kwargs)

    real_reset = worker._Sims.reset

    def reset(self):  # the backends built for the object, read before they are forgotten
        if self.trial_scenes:
            seen["setup"].append(self.setup_seconds())
        real_reset(self)

    monkeypatch.setattr(worker._Sims, "reset", reset)
    monkeypatch.setattr(worker, "generate_contacts", generate)
    monkeypatch.setattr(worker, "refine_grasp", refine)
    monkeypatch.setattr(worker, "refine_verdict", verdict)
    monkeypatch.setattr(worker, "validate_grasp", lambda *a, **k: ValidationResult(True, "success", {}, 0.01))

    def robust(*args, **kwargs):
        failed = (fragile or {}).get(seen["strategies"][-1], 0)
        names = ("pose_1", "pose_2", "mass_x2", "friction_0.5")
        trials = tuple(TrialResult(n, i < 4 - failed, "success" if i < 4 - failed else "dropped", 0.01)
                       for i, n in enumerate(names))  # fmt: skip
        return RobustResult(trials, True)

    monkeypatch.setattr(worker, "robust_validate", robust)
    return seen


def _run(tmp_path, **settings):
    library = {"sources": ["procedural"], "procedural_count": 1}
    config = SynthesisConfig.model_validate({"library": library, "attempts": 3, **settings})
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    return record


@pytest.mark.sim
def test_when_no_side_placement_refines_the_grasp_from_above_is_tried_and_kept(tmp_path, monkeypatch) -> None:
    seen = _doubles(monkeypatch, fails={"horizontal"})
    record = _run(tmp_path)
    assert seen["strategies"] == ["horizontal", "vertical"]
    assert record.strategy == "vertical" and record.contacts.meta["strategy_pca"] == "horizontal"
    assert [a.refinement for a in record.attempts] == ["table_contact"] * 3 + ["ok"]
    assert record.attempt == 3 and record.robust
    assert record.extra["other_strategy"] == {"strategy": "vertical", "first_attempt": 3, "kept": True}
    # both passes' refinements are counted (the resting check adds its own physics time once)
    assert record.steps["refinement"].seconds >= sum(seen["refined"])
    assert record.setup_seconds == pytest.approx(seen["setup"][0])  # every backend of both passes, once
    assert record.approach[2] < -0.99


@pytest.mark.sim
def test_when_both_strategies_fail_the_first_is_kept_and_the_second_is_noted(tmp_path, monkeypatch) -> None:
    seen = _doubles(monkeypatch, fails={"horizontal", "vertical"})
    record = _run(tmp_path)
    assert seen["strategies"] == ["horizontal", "vertical"] and record.strategy == "horizontal"
    assert len(record.attempts) == 6 and record.attempt is None and not record.success
    assert record.extra["other_strategy"] == {
        "strategy": "vertical", "first_attempt": 3, "kept": False, "reason": "refinement: table_contact"
    }  # fmt: skip


@pytest.mark.sim
def test_switched_off_the_pipeline_stops_with_the_first_strategy(tmp_path, monkeypatch) -> None:
    seen = _doubles(monkeypatch, fails={"horizontal"})
    record = _run(tmp_path, other_strategy="never")
    assert seen["strategies"] == ["horizontal"] and record.strategy == "horizontal"
    assert len(record.attempts) == 3 and record.attempt is None and "other_strategy" not in record.extra


@pytest.mark.sim
def test_when_no_side_placement_is_robust_the_robust_grasp_from_above_is_kept(tmp_path, monkeypatch) -> None:
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path)
    assert seen["strategies"] == ["horizontal", "vertical"]
    assert [a.robust for a in record.attempts] == ["friction_0.5"] * 3 + ["ok"]
    assert [a.robustness for a in record.attempts] == [0.75] * 3 + [1.0]
    assert record.strategy == "vertical" and record.attempt == 3 and record.robust
    assert record.extra["other_strategy"] == {"strategy": "vertical", "first_attempt": 3, "kept": True}


@pytest.mark.sim
def test_a_second_strategy_that_holds_no_better_leaves_the_first(tmp_path, monkeypatch) -> None:
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1, "vertical": 2})
    record = _run(tmp_path)
    assert seen["strategies"] == ["horizontal", "vertical"] and record.strategy == "horizontal"
    assert len(record.attempts) == 6 and record.attempt == 0 and record.steps["validation"].ok and not record.robust
    assert record.extra["other_strategy"] == {
        "strategy": "vertical", "first_attempt": 3, "kept": False,
        "reason": "held no better: merit [2, 0.5] against the first strategy's [2, 0.75]",
    }  # fmt: skip


@pytest.mark.sim
@pytest.mark.parametrize("setting", ["failed", True])
def test_failed_tries_the_other_strategy_only_where_nothing_passed(tmp_path, monkeypatch, setting) -> None:
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path, other_strategy=setting)
    assert seen["strategies"] == ["horizontal"] and record.strategy == "horizontal"
    assert len(record.attempts) == 3 and record.attempt == 0 and record.steps["validation"].ok and not record.robust
    assert "other_strategy" not in record.extra


def test_other_strategy_settings() -> None:
    assert SynthesisConfig().other_strategy == "not_robust"
    assert SynthesisConfig(other_strategy=True).other_strategy == "failed"  # the bool of datasets before 12-04
    assert SynthesisConfig(other_strategy=False).other_strategy == "never"
    with pytest.raises(ValueError, match="'never', 'failed' or 'not_robust'"):
        SynthesisConfig(other_strategy="always")


def _tried(primary: tuple[bool, float | None], other: tuple[bool, float | None]):
    """A test double of one placement that passed refinement and SAPIEN's nominal trial, judged (nominal trial
    held, robustness) in SAPIEN (the primary simulator) and PyBullet."""
    from ges_core.dataset import SimVerdict, StepOutcome, TrialVerdict
    from ges_core.synthesis.run.worker import _Attempt

    def verdict(success: bool, robustness: float | None) -> SimVerdict:
        held = round(7 * (robustness or 0.0))
        trials = tuple(TrialVerdict(name=f"t{i}", success=i < held, reason="") for i in range(7)) if success else ()
        return SimVerdict(success=success, reason="success" if success else "palm_only", trials=trials,
                          robustness=robustness if success else None)  # fmt: skip

    sapien, pybullet = verdict(*primary), verdict(*other)
    robust = StepOutcome(ok=True) if sapien.robust else StepOutcome.failed("t6")
    ok = StepOutcome(ok=True)
    return _Attempt(None, None, ok, None, ok, robust, {"sapien": sapien, "pybullet": pybullet}, {}, sapien)


def test_without_a_robust_placement_the_one_that_holds_in_both_engines_is_kept() -> None:
    from ges_core.synthesis.run.worker import _chosen

    fails_in_pybullet = _tried((True, 6 / 7), (False, None))
    holds_in_both = _tried((True, 5 / 7), (True, 5 / 7))
    assert fails_in_pybullet.merit == (1, pytest.approx(3 / 7)) and holds_in_both.merit == (2, pytest.approx(5 / 7))
    assert _chosen([fails_in_pybullet, holds_in_both]) == 1  # before: 0, the primary engine's higher score alone
    robust_in_sapien = _tried((True, 1.0), (False, None))
    assert robust_in_sapien.merit[0] == 3 and _chosen([holds_in_both, robust_in_sapien]) == 1
    everywhere = _tried((True, 1.0), (True, 1.0))
    assert everywhere.merit == (4, 1.0) and _chosen([robust_in_sapien, everywhere, everywhere]) == 1
    weaker = _tried((True, 4 / 7), (True, 4 / 7))
    assert _chosen([weaker, holds_in_both, holds_in_both]) == 1  # the higher mean score, the first of equals
