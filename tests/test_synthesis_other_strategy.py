"""The other grasp strategy: contacts of a forced strategy, and the pipeline's second pass when none of the PCA
strategy's placements passes, or none holds every perturbation trial (``SynthesisConfig.other_strategy``); the
pass of contacts whose thumb balances the squeeze's torque too (``SynthesisConfig.balanced_thumb``)."""

from __future__ import annotations

import dataclasses
import time

import pytest

from ges_core.dataset import open_dataset
from ges_core.errors import ConfigError
from ges_core.objects.library import ObjectLibrary
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS, generate_contacts
from ges_core.synthesis.run.tasks import object_seed

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


TRIALS = ("mass_x2", "friction_0.5", "pose_1", "pose_2")
"""The perturbation trials of these tests, in order (:data:`ROBUST`)."""
ROBUST = {"limits_trial": False, "mass_scales": [2.0], "pose_trials": 2}


def _doubles(monkeypatch, *, fails: set[str], fragile: dict[str, int] | None = None, trial_fails=None) -> dict:
    """Test doubles: refinement's verdict is ``table_contact`` for placements of a strategy in ``fails`` (a strategy
    is named with ``+thumb`` where its contacts' thumb balances the torque too); every
    validation holds; of the four perturbation trials (:data:`TRIALS`), a strategy in ``fragile`` fails that many
    (from the last), the others none; or, given ``trial_fails(placement, simulator, trial) -> bool`` (placement:
    0, 1, ... in the order refined), the trials it says. Returns the strategies generated, each refinement's seconds
    and the trials run (strategy, placement, simulator, trial name), and the contacts generated."""
    from ges_core.synthesis.physics.robust import TrialResult
    from ges_core.synthesis.run import worker
    from ges_core.synthesis.types import ValidationResult

    seen: dict[str, list] = {"strategies": [], "contacts": [], "refined": [], "setup": [], "trials": []}
    placement_of: dict[int, int] = {}  # id of a refined grasp -> its placement
    real_generate, real_refine, real_verdict = worker.generate_contacts, worker.refine_grasp, worker.refine_verdict

    def generate(*args, **kwargs):
        result = real_generate(*args, **kwargs)
        seen["strategies"].append(result.strategy + ("+thumb" if args[2].thumb_balance_torque else ""))
        seen["contacts"].append(result.contacts.positions)
        return result

    def refine(*args, **kwargs):
        refined = real_refine(*args, **kwargs)
        placement_of[id(refined.grasp)] = len(seen["refined"])
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

    def trial(scenes, asset, grasp, pre, config, perturbation, limits):
        strategy, placement = seen["strategies"][-1], placement_of[id(grasp)]
        seen["trials"].append((strategy, placement, scenes.name, perturbation.name))
        if trial_fails is not None:
            held = not trial_fails(placement, scenes.name, perturbation.name)
        else:
            held = TRIALS.index(perturbation.name) < len(TRIALS) - (fragile or {}).get(strategy, 0)
        return TrialResult(perturbation.name, held, "success" if held else "dropped", 0.01)

    monkeypatch.setattr(worker, "run_trial", trial)
    return seen


def _run(tmp_path, **settings):
    """The pipeline on :data:`OID` with the Allegro; the balanced thumb's and the lower raise's passes only where
    ``settings`` ask for them."""
    library = {"sources": ["procedural"], "procedural_count": 1}
    settings = {"balanced_thumb": "never", "low_raise": "never", **settings}
    config = SynthesisConfig.model_validate({"library": library, "attempts": 3, "robust": ROBUST, **settings})
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
    assert [a.robust for a in record.attempts] == ["pose_2"] * 3 + ["ok"]
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


@pytest.mark.sim
def test_without_validation_only_a_pair_with_nothing_refined_tries_the_other_strategy(tmp_path, monkeypatch):
    """With ``validate_sims: []`` a placement that refined holds everywhere there is to hold (merit level 4: no
    trial can tell one pass's placement from another's), so 'not_robust' sends on only the pairs whose placements all
    failed refinement."""
    seen = _doubles(monkeypatch, fails=set())
    record = _run(tmp_path / "refined", validate_sims=[])
    assert seen["strategies"] == ["horizontal"] and "other_strategy" not in record.extra
    assert record.attempt == 0 and record.steps["validation"].reason == "not_run"
    seen = _doubles(monkeypatch, fails={"horizontal"})
    record = _run(tmp_path / "none_refined", validate_sims=[])
    assert seen["strategies"] == ["horizontal", "vertical"] and record.extra["other_strategy"]["kept"]


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


# -- robust.defer_trials: a placement's trials stop at its first failure, the rest run only when needed --------
def _compared(tmp_path, monkeypatch, trial_fails, **settings):
    """The record and the trials run, with ``robust.defer_trials`` on and off (same doubles, same inputs)."""
    out = {}
    for defer in (True, False):
        seen = _doubles(monkeypatch, fails=set(), trial_fails=trial_fails)
        robust = ROBUST | {"defer_trials": defer}
        out[defer] = (_run(tmp_path / str(defer), robust=robust, **settings), seen["trials"])
        monkeypatch.undo()  # the second run's doubles wrap the real functions, not the first run's doubles
    return out


def _same_outcome(a, b) -> None:
    """Two records keep the same placement with the same verdicts and joints (attempt robustness aside)."""
    assert a.attempt == b.attempt and a.strategy == b.strategy and a.validations == b.validations
    assert [(v.refinement, v.validation, v.robust) for v in a.attempts] == [
        (v.refinement, v.validation, v.robust) for v in b.attempts
    ]
    assert (a.grasp.q == b.grasp.q).all() and a.robust == b.robust


@pytest.mark.sim
def test_deferred_trials_stop_at_the_first_failure_when_a_later_placement_holds(tmp_path, monkeypatch) -> None:
    runs = _compared(tmp_path, monkeypatch, lambda placement, sim, trial: placement == 0 and trial == "friction_0.5")
    (deferred, ran_deferred), (full, ran_full) = runs[True], runs[False]
    _same_outcome(deferred, full)
    assert deferred.attempt == 1 and deferred.robust and deferred.attempts[0].robust == "friction_0.5"
    assert [t[1:] for t in ran_deferred[:2]] == [(0, "sapien", "mass_x2"), (0, "sapien", "friction_0.5")]
    assert len(ran_deferred) == 2 + 4 and len(ran_full) == 4 + 4  # pose_1 and pose_2 of placement 0 never ran
    assert deferred.attempts[0].robustness is None and full.attempts[0].robustness == 0.75  # not a score of 2 trials


@pytest.mark.sim
def test_deferred_trials_run_after_all_when_no_placement_holds(tmp_path, monkeypatch) -> None:
    runs = _compared(tmp_path, monkeypatch, lambda placement, sim, trial: trial == "friction_0.5")
    (deferred, ran_deferred), (full, ran_full) = runs[True], runs[False]
    _same_outcome(deferred, full)
    assert len(deferred.attempts) == 6 and deferred.extra == full.extra  # both strategies tried, the first kept
    assert [a.robustness for a in deferred.attempts] == [a.robustness for a in full.attempts] == [0.75] * 6
    assert sorted(ran_deferred) == sorted(ran_full)  # the same trials: the choice compares every score
    assert ran_deferred != ran_full  # each placement's last two ran after the others' first two


@pytest.mark.sim
def test_a_placement_that_failed_in_one_engine_defers_the_other_engines_trials(tmp_path, monkeypatch) -> None:
    runs = _compared(
        tmp_path,
        monkeypatch,
        lambda placement, sim, trial: (placement, sim, trial) == (0, "sapien", "friction_0.5"),
        validate_sims=["sapien", "pybullet"],
    )
    (deferred, ran_deferred), (full, ran_full) = runs[True], runs[False]
    _same_outcome(deferred, full)
    assert deferred.attempt == 1 and deferred.robust
    assert [t[1:3] for t in ran_deferred].count((0, "pybullet")) == 0  # it could not hold everywhere any more
    assert len(ran_deferred) == 2 + 4 + 4 and len(ran_full) == 4 * 4


@pytest.mark.sim
def test_a_backend_that_fails_for_deferred_trials_makes_that_placement_unstable(tmp_path, monkeypatch) -> None:
    """Every placement fails friction_0.5, so their deferred trials run after the loop; the backend for placement 0's
    first deferred trial fails to build: that placement's verdict becomes ``unstable`` (as when it fails during
    validation) and the record keeps the next placement, the first of the rest (equal merits)."""
    from ges_core.errors import SimulationError
    from ges_core.synthesis.run import worker

    seen = _doubles(monkeypatch, fails=set(), trial_fails=lambda placement, sim, trial: trial == "friction_0.5")
    doubled = worker.run_trial

    def trial(scenes, asset, grasp, pre, config, perturbation, limits):
        result = doubled(scenes, asset, grasp, pre, config, perturbation, limits)
        if seen["trials"][-1][1:] == (0, "sapien", "pose_1"):
            raise SimulationError("sapien: the scene failed to build")
        return result

    monkeypatch.setattr(worker, "run_trial", trial)
    record = _run(tmp_path, other_strategy="never")
    assert [a.validation for a in record.attempts] == ["unstable", "ok", "ok"]
    assert record.attempt == 1 and [a.robustness for a in record.attempts] == [None, 0.75, 0.75]


@pytest.mark.sim
def test_where_no_placement_is_robust_contacts_with_a_balanced_thumb_are_tried_and_kept(tmp_path, monkeypatch):
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path, other_strategy="never", balanced_thumb="not_robust")
    assert seen["strategies"] == ["horizontal", "horizontal+thumb"]
    assert [a.robust for a in record.attempts] == ["pose_2"] * 3 + ["ok"]
    assert record.attempt == 3 and record.robust and record.strategy == "horizontal"
    assert record.extra["balanced_thumb"] == {"first_attempt": 3, "kept": True}
    first, balanced = seen["contacts"]
    assert (first != balanced).any()  # the thumb moved
    assert (record.contacts.positions == balanced).all()  # and the record keeps the pass it chose


@pytest.mark.sim
def test_after_the_other_strategy_the_balanced_thumb_pass_starts_from_the_pass_kept(tmp_path, monkeypatch):
    """The grasp from above holds worse than the side grasp: the side grasp's contacts are kept, and the balanced
    thumb is tried on them (the can's rim from above balances its thumb already: the same contacts there)."""
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 2, "vertical": 3})
    record = _run(tmp_path, balanced_thumb="not_robust")
    assert seen["strategies"] == ["horizontal", "vertical", "horizontal+thumb"]
    assert len(record.attempts) == 7 and record.attempt == 6 and record.robust and record.strategy == "horizontal"
    assert record.extra["other_strategy"] == {
        "strategy": "vertical", "first_attempt": 3, "kept": False,
        "reason": "held no better: merit [2, 0.25] against the first strategy's [2, 0.5]",
    }  # fmt: skip
    assert record.extra["balanced_thumb"] == {"first_attempt": 6, "kept": True}


@pytest.mark.sim
def test_no_balanced_thumb_pass_where_a_placement_is_robust_or_the_thumb_does_not_move(tmp_path, monkeypatch):
    """Where a placement is robust the pass is not asked for (no note); where the balanced thumb's contacts are the
    first ones, or cannot be made, it is asked for and has nothing to retarget: the note says why, and the contact
    step's seconds count both generations."""
    from ges_core.errors import SynthesisError
    from ges_core.synthesis.run import worker

    seen = _doubles(monkeypatch, fails=set())
    record = _run(tmp_path / "robust", balanced_thumb="not_robust")
    assert seen["strategies"] == ["horizontal"] and record.robust and "balanced_thumb" not in record.extra

    real = worker.generate_contacts

    def same(points, normals, config, **kwargs):  # the first contacts again, half a second later
        if config.thumb_balance_torque:
            time.sleep(0.5)
        return real(points, normals, type(config)(), **kwargs)

    monkeypatch.setattr(worker, "generate_contacts", same)
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path / "same", other_strategy="never", balanced_thumb="not_robust")
    assert seen["strategies"] == ["horizontal", "horizontal+thumb"]  # asked for, the same contacts: no second pass
    assert len(record.attempts) == 3 and not record.robust
    assert record.extra["balanced_thumb"] == {"kept": False, "reason": "contacts: same contacts"}
    assert record.steps["contacts"].seconds >= 0.5  # the second generation counted

    def unbalanceable(points, normals, config, **kwargs):
        if config.thumb_balance_torque:
            raise SynthesisError("no thumb placement balances it", reason="no_thumb_site")
        return real(points, normals, config, **kwargs)

    monkeypatch.setattr(worker, "generate_contacts", unbalanceable)
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path / "failed", other_strategy="never", balanced_thumb="not_robust")
    assert seen["strategies"] == ["horizontal"] and len(record.attempts) == 3
    assert record.extra["balanced_thumb"] == {"kept": False, "reason": "contacts: no_thumb_site"}


def _raises(monkeypatch) -> list[float]:
    """Each retargeting call's raise (``min_contact_height``, metres), in order, read from the retargeter that
    solves it."""
    from ges_core.synthesis.retarget.retargeter import GraspRetargeter

    raises, real = [], GraspRetargeter.retarget_ranked

    def ranked(self, *args, **kwargs):
        raises.append(self.config.min_contact_height)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(GraspRetargeter, "retarget_ranked", ranked)
    return raises


@pytest.mark.sim
def test_where_no_placement_is_robust_the_kept_contacts_are_retargeted_with_a_lower_raise(tmp_path, monkeypatch):
    """The can's side contacts lie partly below the 25 mm raise: the pass retargets the very contacts at 20 mm (the
    Allegro's own height) and keeps its placement that holds better; the contacts' seconds are counted once."""
    from ges_core.synthesis.run import worker

    raises = _raises(monkeypatch)
    real_generate = worker.generate_contacts

    def slow(*args, **kwargs):  # contacts that take half a second
        time.sleep(0.5)
        return real_generate(*args, **kwargs)

    monkeypatch.setattr(worker, "generate_contacts", slow)
    seen = _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    real_trial = worker.run_trial

    def trial(scenes, asset, grasp, pre, config, perturbation, limits):  # the lower raise's placements all hold
        result = real_trial(scenes, asset, grasp, pre, config, perturbation, limits)
        return dataclasses.replace(result, success=True, reason="success") if raises[-1] < 0.025 else result

    monkeypatch.setattr(worker, "run_trial", trial)
    record = _run(tmp_path, other_strategy="never", low_raise="not_robust")
    assert 0.5 <= record.steps["contacts"].seconds < 1.0
    assert raises == [0.025, 0.02] and seen["strategies"] == ["horizontal"]  # one generation, two retargetings
    assert seen["contacts"][0][:, 2].min() < 0.025  # a contact the first raise moved up
    assert [a.robust for a in record.attempts] == ["pose_2"] * 3 + ["ok"]
    assert record.attempt == 3 and record.robust
    assert record.extra["low_raise"] == {"first_attempt": 3, "kept": True}
    assert (record.contacts.positions == seen["contacts"][0]).all()  # the same contacts


HIGHER = {"allegro": {"retarget": {"low_raise_height": 0.03}}}
"""A "lower" raise above the run's 25 mm (per hand: it wins over the hand's own YAML)."""


@pytest.mark.sim
def test_the_lower_raise_has_nothing_to_try_where_no_contact_lies_between_the_raises(tmp_path, monkeypatch):
    raises = _raises(monkeypatch)
    _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path / "same", other_strategy="never", low_raise="not_robust", hand_settings=HIGHER)
    assert raises == [0.025] and len(record.attempts) == 3  # not lower than the run's raise: nothing to try
    assert record.extra["low_raise"] == {"kept": False, "reason": "contacts: none lower"}
    _doubles(monkeypatch, fails=set(), fragile={"horizontal": 1})
    record = _run(tmp_path / "never", other_strategy="never")
    assert raises == [0.025, 0.025] and "low_raise" not in record.extra


def test_balanced_thumb_settings() -> None:
    assert SynthesisConfig().balanced_thumb == "not_robust"
    assert SynthesisConfig().dump()["balanced_thumb"] == "not_robust"  # stored: a folder written without it is refused
    with pytest.raises(ValueError, match="'never' or 'not_robust'"):
        SynthesisConfig(balanced_thumb="always")


def test_low_raise_settings() -> None:
    config = SynthesisConfig()
    assert (config.low_raise, config.retarget.low_raise_height) == ("not_robust", 0.015)
    assert config.retarget.low_raise_height < config.retarget.min_contact_height
    stored = config.dump()  # stored: a folder written without them is refused
    assert stored["low_raise"] == "not_robust" and stored["retarget"]["low_raise_height"] == 0.015
    shadow = SynthesisConfig(hand_settings={"shadow": {"retarget": {"low_raise_height": 0.02}}}).for_hand("shadow")
    assert shadow.retarget.low_raise_height == 0.02  # per hand, like any step's setting
    with pytest.raises(ValueError, match="greater than or equal to 0"):
        SynthesisConfig(retarget={"low_raise_height": -0.01})


def test_the_built_in_hands_lower_raise_heights() -> None:
    """The Allegro's YAML sets its own height (its 12 mm fingertips); the Shadow runs the default."""
    from ges_core.registry import load_registry

    registry = load_registry()
    heights = {
        name: SynthesisConfig().for_hand(name, registry.build_hand(name).description.settings).retarget.low_raise_height
        for name in ("allegro", "shadow")
    }
    assert heights == {"allegro": 0.02, "shadow": 0.015}


@pytest.mark.sim
def test_the_balanced_thumb_pass_runs_for_real_where_no_placement_can_hold(tmp_path) -> None:
    """No double: every placement of the can faces a trial at 100 times its mass, which no placement holds, so after
    the first contacts' placements the pipeline generates the balanced thumb's (the side grasp's thumb moves on this
    can) and takes them through the same steps; the note says where its placements begin, and the record keeps one
    pass's contacts."""
    library = {"sources": ["procedural"], "procedural_count": 1}
    robust = {"limits_trial": False, "mass_scales": [100.0], "friction_floor": None, "pose_trials": 0}
    config = SynthesisConfig.model_validate(
        {"library": library, "attempts": 2, "robust": robust, "other_strategy": "never", "low_raise": "never"}
    )  # the default balanced_thumb: not_robust
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    note = record.extra["balanced_thumb"]
    assert not record.robust and note["first_attempt"] == 2 and len(record.attempts) == 4
    first = generate_contacts(
        *config.library.build().point_cloud(OID, config.points, seed=object_seed(config.seed, OID)),
        config.contacts, object_id=OID, seed=object_seed(config.seed, OID), center_of_mass=LIBRARY_CENTER_OF_MASS,
    ).contacts.positions  # fmt: skip
    assert (record.contacts.positions == first).all() != note["kept"]
    assert note["kept"] or note["reason"].startswith(("held no better", "refinement", "validation", "retargeting"))


@pytest.mark.sim
def test_the_lower_raise_pass_runs_for_real_where_no_placement_can_hold(tmp_path) -> None:
    """No double: no placement holds the can at 100 times its mass, so after the first placements the pipeline
    retargets the same contacts with the lower raise and takes those placements through the same steps."""
    library = {"sources": ["procedural"], "procedural_count": 1}
    robust = {"limits_trial": False, "mass_scales": [100.0], "friction_floor": None, "pose_trials": 0}
    settings = {"attempts": 2, "robust": robust, "other_strategy": "never", "balanced_thumb": "never"}
    config = SynthesisConfig.model_validate({"library": library, **settings})  # the default low_raise: not_robust
    run_synthesis([OID], ["allegro"], config, tmp_path / "ds")
    (record,) = open_dataset(tmp_path / "ds")
    note = record.extra["low_raise"]
    assert not record.robust and note["first_attempt"] == 2 and len(record.attempts) == 4
    assert note["kept"] or note["reason"].startswith(("held no better", "refinement", "validation", "retargeting"))
    assert record.steps["retargeting"].ok
