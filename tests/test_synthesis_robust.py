"""Robust validation (ges_core.synthesis.physics.robust): its config, its perturbations, and a real run.

The real run takes one object through the whole pipeline with both engines and a deliberately weak perturbation
(the object 30 times heavier, every drive at the Allegro's 0.5 N·m): the nominal trial and the drive-limits trial
hold, the heavy trial fails, and the record stores each verdict beside the paper's single-trial one.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ges_core import cli
from ges_core.config import parse_model
from ges_core.dataset import open_dataset
from ges_core.errors import ConfigError, SimulationError
from ges_core.objects.asset import ObjectAsset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.synthesis.physics.robust import RobustConfig, object_friction_for, perturbations, robust_validate
from ges_core.synthesis.physics.scene import TrialScenes
from ges_core.synthesis.physics.validate import ValidateConfig, shifted, validate_grasp
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.pipeline import run_synthesis
from ges_core.synthesis.types import Grasp
from ges_core.transforms import quat_to_matrix

from helpers_sim import box_asset


def _asset(friction: float = 1.0) -> ObjectAsset:
    return ObjectAsset(object_id="t/box", category="box", mesh_path="x.obj", collision=(), friction=friction)


def test_default_trials_and_their_order():
    names = [p.name for p in perturbations(RobustConfig(), 1.0, _asset(), seed=7)]
    assert names == ["limits", "mass_x0.5", "mass_x2", "friction_0.5", "pose_1", "pose_2", "pose_3"]
    assert RobustConfig().trial_count == len(names)


def test_pose_offsets_are_seeded_and_sized_as_configured():
    config = RobustConfig(pose_trials=4, pose_shift=0.004, pose_turn_deg=6.0)
    shifts = [p.shift for p in perturbations(config, 1.0, _asset(), seed=3) if p.shift is not None]
    again = [p.shift for p in perturbations(config, 1.0, _asset(), seed=3) if p.shift is not None]
    other = [p.shift for p in perturbations(config, 1.0, _asset(), seed=4) if p.shift is not None]
    assert len(shifts) == 4 and all(np.array_equal(a, b) for a, b in zip(shifts, again, strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(shifts, other, strict=True))
    for shift in shifts:
        assert math.isclose(np.linalg.norm(shift[:3]), 0.004, rel_tol=1e-12) and shift[2] == 0.0  # in the table plane
        turn = 2 * math.degrees(math.atan2(np.linalg.norm(shift[4:]), shift[3]))
        assert math.isclose(turn, 6.0, rel_tol=1e-9) and shift[4] == shift[5] == 0.0  # about the vertical
    directions = {round(math.degrees(math.atan2(s[1], s[0]))) for s in shifts}
    assert len(directions) == 4  # four headings, not one repeated


@pytest.mark.parametrize(("floor", "hand", "obj", "expected"), [(0.5, 1.0, 1.0, 0.0), (0.6, 0.8, 1.0, 0.4)])
def test_friction_trial_sets_the_effective_coefficient_to_the_floor(floor, hand, obj, expected):
    mu = object_friction_for(floor, hand, obj)
    assert math.isclose(mu, expected, abs_tol=1e-12) and math.isclose((hand + mu) / 2, floor)


def test_friction_trial_never_raises_the_objects_friction_and_says_when_the_floor_is_out_of_reach():
    assert object_friction_for(0.5, 0.4, 0.3) == 0.3  # effective 0.35 is below the floor already
    with pytest.raises(ConfigError, match=r"lowest effective hand-object friction is 0.5 \(the engines average"):
        object_friction_for(0.3, 1.0, 1.0)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"robust": {"mass_scales": [0.5, -1.0]}}, r"robust.mass_scales: .*finite and > 0, got \[-1.0\]"),
        ({"robust": {"mass_scales": [2.0, 2.0]}}, r"robust.mass_scales: .*lists a density factor twice"),
        ({"robust": {"pose_shift": 0.2}}, r"robust.pose_shift"),
        (
            {"robust": {"mass_scales": [], "friction_floor": None, "pose_trials": 0, "limits_trial": False}},
            r"robust validation is enabled but runs no trial",
        ),
        ({"robust": {"friction_floor": 0.3}}, r"robust.friction_floor=0.3 cannot be reached with scene.hand_friction"),
        ({"robust": {"retries": True}}, r"robust.retries"),
    ],
)
def test_bad_robust_settings_say_what_to_change(data, message):
    with pytest.raises(ConfigError, match=message):
        parse_model(SynthesisConfig, data, where="test")


def test_shifted_moves_in_the_world_and_turns_about_the_objects_own_origin():
    rest = np.array([0.1, -0.2, 0.03, math.cos(0.3), 0.0, 0.0, math.sin(0.3)])  # already turned 0.6 rad about z
    quarter = np.array([0.004, 0.003, 0.0, math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    moved = shifted(rest, quarter)
    np.testing.assert_allclose(moved[:3], [0.104, -0.197, 0.03])
    expected = quat_to_matrix(quarter[3:]) @ quat_to_matrix(rest[3:])
    np.testing.assert_allclose(quat_to_matrix(moved[3:]), expected, atol=1e-12)


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_a_trial_moves_the_object_and_lifts_its_caps_afterwards(sim_name):
    """validate_grasp(object_shift=..., drive_limits=...): the object starts where the shift puts it, the caps are
    set after staging and lifted when the trial ends (spied on a real backend; a 4-step protocol)."""
    registry = load_registry()
    hand = registry.build_hand("allegro")
    sim = registry.build_sim(sim_name, SceneConfig())
    calls, placed = [], []
    set_limits, set_pose = sim.set_drive_limits, sim.set_object_pose
    sim.set_drive_limits = lambda limits: (calls.append(limits), set_limits(limits))[1]
    sim.set_object_pose = lambda pose, **kw: (placed.append(np.array(pose)), set_pose(pose, **kw))[1]
    far = Grasp(hand="allegro", wrist_pose=np.array([0, 0, 0.4, 1.0, 0, 0, 0]), q=np.zeros(16))
    quick = ValidateConfig(approach_steps=1, close_steps=1, lift_steps=1, hold_steps=1)
    shift = np.array([0.005, 0.0, 0.0, math.cos(0.05), 0.0, 0.0, math.sin(0.05)])
    limits = np.full(16, 0.5)
    result = validate_grasp(sim, hand, box_asset(), far, far, quick, object_shift=shift, drive_limits=limits)
    assert result.reason == "no_contact"  # the hand stayed 40 cm up
    assert len(calls) == 2 and np.array_equal(calls[0], limits) and calls[1] is None
    (start,) = placed
    rest = sim.object_pose()[0]  # nothing touched it: it stayed at the shifted start
    np.testing.assert_allclose(start[0], rest, atol=2e-3)
    np.testing.assert_allclose(start[0, :2], [0.005, 0.0], atol=1e-9)
    sim.close()


def test_every_trial_squeezes_for_the_nominal_objects_mass(monkeypatch):
    """The hand is told of the object, not of the perturbation: each trial validates the perturbed object (twice or
    half the mass) but sizes the squeeze (``squeeze_mass``, the thumb's force) for the nominal one."""
    from contextlib import contextmanager

    import ges_core.synthesis.physics.robust as robust
    from ges_core.synthesis.types import ValidationResult

    seen = []

    def fake_validate(sim, hand, asset, grasp, pre, config, **kw):
        seen.append((asset.mass, kw["squeeze_mass"]))
        return ValidationResult(True, "success")

    class Scenes:  # what robust_validate reads of its TrialScenes: the hand, the scene config, open()
        hand = load_registry().build_hand("shadow")
        config = SceneConfig()

        @contextmanager
        def open(self):
            yield None

    monkeypatch.setattr(robust, "validate_grasp", fake_validate)
    obj = replace(_asset(), mass=0.6)
    config = RobustConfig(mass_scales=(0.5, 2.0), friction_floor=None, pose_trials=1, limits_trial=False)
    result = robust_validate(Scenes(), obj, None, None, ValidateConfig(), config, seed=0)
    assert [t.name for t in result.trials] == ["mass_x0.5", "mass_x2", "pose_1"]
    assert seen == [(pytest.approx(0.3), 0.6), (pytest.approx(1.2), 0.6), (0.6, 0.6)]


def test_switched_off_needs_no_trial():
    off = {"enabled": False, "mass_scales": [], "friction_floor": None, "pose_trials": 0, "limits_trial": False}
    assert not parse_model(SynthesisConfig, {"robust": off}, where="test").robust.enabled


@pytest.fixture(scope="module")
def weak_box_run(tmp_path_factory):
    """The Allegro box record of one pipeline run with a deliberately weak perturbation, validated in both engines;
    its config and dataset folder."""
    config = parse_model(
        SynthesisConfig,
        {
            "validate_sims": ["sapien", "pybullet"],
            "attempts": 1,
            "robust": {"mass_scales": [30.0], "friction_floor": None, "pose_trials": 1},
        },
        where="test",
    )
    folder = tmp_path_factory.mktemp("weak") / "ds"
    run_synthesis(["procedural/box/000"], ["allegro"], config, folder, progress=False)
    (record,) = list(open_dataset(folder))
    return record, config, folder


def _stored_grasp(run):
    """The registry, the Allegro, its settings of the run's config, the object, and the record's grasp and pre-grasp."""
    record, config, _ = run
    registry = load_registry()
    hand = registry.build_hand("allegro")
    cfg = config.for_hand("allegro", hand.description.settings)
    obj = cfg.library.build().get(record.object_id)
    grasp = Grasp("allegro", record.grasp.wrist_pose, record.grasp.q)
    pre = Grasp("allegro", record.pregrasp.wrist_pose, record.pregrasp.q)
    return registry, hand, cfg, obj, grasp, pre


@pytest.mark.sim
def test_a_weak_perturbation_fails_where_the_nominal_trial_passes(weak_box_run):
    """Allegro on the box, SAPIEN and PyBullet: nominal and drive-limits trials hold, 30 times the mass does not."""
    record, _, _ = weak_box_run
    assert record.steps["validation"].ok and not record.robust
    assert record.steps["robust"].reason == "mass_x30" and record.robustness <= 2 / 3
    for sim in ("sapien", "pybullet"):
        verdict = record.validations[sim]
        assert verdict.success, (sim, verdict)  # the paper's single trial
        assert [t.name for t in verdict.trials] == ["limits", "mass_x30", "pose_1"], sim
        assert verdict.trials[0].success and not verdict.trials[1].success, (sim, verdict.trials)
        assert verdict.trials[1].reason in ("not_lifted", "dropped")
        assert verdict.robustness == pytest.approx(sum(t.success for t in verdict.trials) / 3)
        assert verdict.robust_seconds > 0
    assert record.attempts[0].robust == "mass_x30" and record.attempts[0].robustness == record.robustness
    assert record.total_seconds == pytest.approx(sum(record.steps[s].seconds for s in record.steps if s != "robust"))


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_a_stored_verdict_replays_exactly_outside_the_pipeline(weak_box_run, sim_name):
    """Every trial runs in a backend of its own, so the record's verdicts are the grasp's own: replaying the stored
    grasp alone (the nominal trial in a new backend, then robust_validate) gives every stored reason and flag."""
    record, _, _ = weak_box_run
    registry, hand, cfg, obj, grasp, pre = _stored_grasp(weak_box_run)
    built = []
    scenes = TrialScenes(lambda *a: built.append(a) or registry.build_sim(*a), sim_name, cfg.scene, hand)
    stored = record.validations[sim_name]
    with scenes.open() as sim:
        nominal = validate_grasp(sim, hand, obj, grasp, pre, cfg.validate_)
    assert (nominal.reason, nominal.flags) == (stored.reason, dict(stored.flags))
    replay = robust_validate(scenes, obj, grasp, pre, cfg.validate_, cfg.robust, seed=record.seed)
    assert [(t.name, t.reason) for t in replay.trials] == [(t.name, t.reason) for t in stored.trials]
    assert len(built) == 1 + len(replay.trials) and scenes.seconds > 0  # a backend per trial


@pytest.mark.sim
def test_the_fingertips_bound_lies_between_the_trial_that_held_and_the_one_that_did_not(weak_box_run, capsys):
    """The box grasp held the drive-limits trial and dropped 30 times the mass in both engines, so what its fingertips
    can hold within the Allegro's 0.5 N·m (ges_core.synthesis.physics.capacity, a linear program on forward
    kinematics, no simulator) must lie between 1 and 30 weights; ``ges dataset capacity`` sets both trials beside
    that bound (limits within it, mass_x30 beyond), per simulator."""
    from ges_core.synthesis.physics.capacity import fingertip_capacity
    from ges_core.synthesis.physics.robust import effective_friction
    from ges_core.synthesis.run.capacity import CLOUD_POINTS

    record, config, folder = weak_box_run
    hand = load_registry().build_hand("allegro")
    library = config.library.build()
    obj = library.get(record.object_id)
    points, normals = library.point_cloud(record.object_id, CLOUD_POINTS, seed=0)
    grasp = Grasp("allegro", record.grasp.wrist_pose, record.grasp.q)
    mu = effective_friction(config.scene.hand_friction, obj.friction)
    tip = fingertip_capacity(hand, grasp, points, normals, mu, contacts=record.contacts)  # as the command reads it
    assert len(tip.fingers) >= 2 and 1.0 <= tip.ratio(obj.mass, abs(config.scene.gravity)) < 30.0, (tip, obj.mass)
    assert cli.main(["dataset", "capacity", str(folder)]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| allegro | procedural/box/000 |"))
    assert row.endswith("| py+ sa+ | py-! sa-! |"), row  # limits, mass_x30 (pose trials are not bounded)
    assert "| allegro | 2 | 0 | 2 | 0 |" in out  # failed beyond, failed within, passed within, passed beyond


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_the_fingers_a_close_leaves_pressing_are_those_the_engine_lists_on_the_object(weak_box_run, sim_name, capsys):
    """``pressing_fingers`` runs the limits trial's approach and close: the fingers it names are those whose tip
    links the engine's slow pair list (another reading of its contacts) shows pushing the object right after, the
    thumb among them on this held grasp; ``ges dataset capacity --pressing SIM`` lists the same fingers in the
    record's row and bounds the trials with them alone."""
    from ges_core.synthesis.physics.robust import trial_limits
    from ges_core.synthesis.physics.validate import pressing_fingers

    folder = weak_box_run[2]
    registry, hand, cfg, obj, grasp, pre = _stored_grasp(weak_box_run)
    scenes = TrialScenes(registry.build_sim, sim_name, cfg.scene, hand)
    with scenes.open() as sim:
        limits = trial_limits(scenes, cfg.robust)
        pressing = pressing_fingers(sim, hand, obj, grasp, pre, cfg.validate_, drive_limits=limits)
        pushed: dict[str, float] = {}
        for pair in sim.contact_pairs(0):
            if {pair.body_a, pair.body_b} == {"hand", "object"}:
                link = pair.link_a if pair.body_a == "hand" else pair.link_b
                pushed[link] = pushed.get(link, 0.0) + pair.force
    d = hand.description
    listed = tuple(f.name for f in d.fingers if pushed.get(f.tip_link, 0.0) > cfg.validate_.min_tip_force)
    assert pressing == listed and "thumb" in pressing and len(pressing) >= 2, (pressing, pushed)
    assert cli.main(["dataset", "capacity", str(folder), "--pressing", sim_name]) == 0
    row = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| allegro | procedural/box/000 |"))
    assert f"| {len(pressing)} of {'+'.join(pressing)} |" in row, row
    assert cli.main(["dataset", "capacity", str(folder), "--pressing", "mujocoo"]) == 1
    assert "mujocoo" in capsys.readouterr().err


@pytest.mark.sim
def test_a_replay_that_blows_up_is_named_and_the_command_goes_on(weak_box_run, monkeypatch, capsys):
    """A simulator that explodes while ``--pressing`` replays a record's close (made to raise here: no stored grasp
    blows up a real engine) costs that record's row, not the command: it ends normally, names the record and the
    error, and counts none of its trials; the plain bound (no replay) is untouched."""
    from ges_core.errors import SimulationError
    from ges_core.synthesis.run import capacity

    folder = weak_box_run[2]

    def explode(*args, **kwargs):
        raise SimulationError("object position is NaN after step 40")

    monkeypatch.setattr(capacity, "_pressing", explode)
    assert cli.main(["dataset", "capacity", str(folder), "--pressing", "sapien"]) == 0
    out = capsys.readouterr().out
    assert "not replayed: allegro / procedural/box/000: SimulationError: object position is NaN after step 40" in out
    assert "| allegro | procedural/box/000 |" not in out and "| allegro | 0 | 0 | 0 | 0 |" in out  # no row, no count
    rows = capacity.trial_bounds(folder, load_registry(), pressing="sapien")
    assert [(r["object"], r["trials"], "pressing_error" in r) for r in rows] == [("procedural/box/000", {}, True)]
    assert capacity.bound_counts(rows) == {"allegro": {}}
    assert cli.main(["dataset", "capacity", str(folder)]) == 0  # without --pressing nothing is replayed
    assert "| allegro | procedural/box/000 |" in capsys.readouterr().out


@pytest.mark.sim
def test_capacity_of_a_hand_the_dataset_does_not_hold_names_the_hands_it_does(weak_box_run, capsys):
    """``--hand shadow`` on a dataset of Allegro records is an error naming the hands it holds, not an empty
    table (a typo read as "no record with trials" before); ``--hand allegro`` still gives the table."""
    _, _, folder = weak_box_run
    assert cli.main(["dataset", "capacity", str(folder), "--hand", "shadow"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "holds no record of hand shadow; its records are of: allegro" in captured.err
    assert cli.main(["dataset", "capacity", str(folder), "--hand", "allegro"]) == 0
    assert "| allegro | procedural/box/000 |" in capsys.readouterr().out


@pytest.mark.sim
def test_deferred_trials_keep_the_record_and_skip_a_failed_placements_other_trials(tmp_path, monkeypatch):
    """Allegro, ``procedural/box/000``, SAPIEN: its first placement passes the nominal trial and every perturbation
    trial with margin, and so does its second. The first placement's first trial (the drive limits) is made to fail
    here (its real verdict replaced by 'dropped'; the trial itself runs), so that the loop must go on to the second.
    With ``robust.defer_trials`` the first placement's six other trials never run, and the record is the one every
    trial gives. (It used ``procedural/cross/002``, whose first placement failed the limits trial on its own; on
    another machine that placement failed its nominal trial instead: a marginal grasp is no fixture.)"""
    import ges_core.synthesis.run.worker as worker

    records, builds, real_build = {}, [], TrialScenes.build
    monkeypatch.setattr(TrialScenes, "build", lambda self: builds.append(self.name) or real_build(self))
    real_trial, first = worker.run_trial, {}

    def first_trial_fails(scenes, asset, grasp, pre, cfg, p, limits):
        verdict = real_trial(scenes, asset, grasp, pre, cfg, p, limits)
        first.setdefault("pose", grasp.wrist_pose.tobytes())  # the first placement to reach its trials
        first.setdefault("trial", p.name)
        if (grasp.wrist_pose.tobytes(), p.name) == (first["pose"], first["trial"]):
            return replace(verdict, success=False, reason="dropped")
        return verdict

    monkeypatch.setattr(worker, "run_trial", first_trial_fails)
    counts = {}
    for defer in (True, False):
        builds.clear()
        first.clear()
        config = parse_model(
            SynthesisConfig,
            {"library": {"sources": ["procedural"], "procedural_count": 3}, "robust": {"defer_trials": defer}},
            where="test",
        )
        run_synthesis(["procedural/box/000"], ["allegro"], config, tmp_path / str(defer), progress=False)
        (records[defer],) = list(open_dataset(tmp_path / str(defer)))
        counts[defer] = len(builds)  # a backend per rest check, refinement, nominal trial and perturbation trial
    deferred, full = records[True], records[False]
    assert first["trial"] == "limits" and full.attempts[0].validation == "ok"  # the case this test is about
    assert full.attempts[0].robust == "limits" and full.attempt == 1 and full.robust
    assert full.attempts[0].robustness == pytest.approx(6 / 7)  # the six real trials held
    assert deferred.attempts[0].robust == "limits" and deferred.attempts[0].robustness is None
    assert (deferred.attempt, deferred.robust, deferred.robustness) == (full.attempt, full.robust, full.robustness)
    assert (deferred.grasp.q == full.grasp.q).all() and (deferred.grasp.wrist_pose == full.grasp.wrist_pose).all()
    a, b = deferred.validations["sapien"], full.validations["sapien"]
    assert (a.success, a.reason, dict(a.flags), a.trials) == (b.success, b.reason, dict(b.flags), b.trials)
    assert counts[False] - counts[True] == 6


class _Backend:
    """Test double of a backend: records what TrialScenes does with it."""

    def __init__(self, log: list) -> None:
        self.log, self.name = log, "double"

    def load_hand(self, hand, floating):
        self.log.append(("hand", id(self), hand, floating))

    def close(self):
        self.log.append(("close", id(self)))


def test_trial_scenes_build_a_new_backend_per_trial_and_close_it_even_after_an_error():
    log, hand = [], load_registry().build_hand("allegro")
    built = []
    scenes = TrialScenes(lambda name, cfg: built.append((name, cfg)) or _Backend(log), "sapien", SceneConfig(), hand)
    with scenes.open() as first:
        pass
    with pytest.raises(RuntimeError), scenes.open() as second:
        raise RuntimeError("a trial that fails")
    assert first is not second and built == [("sapien", SceneConfig())] * 2
    assert log == [("hand", id(first), hand, True), ("close", id(first)), ("hand", id(second), hand, True),
                   ("close", id(second))]  # fmt: skip


def test_trial_scenes_close_a_backend_whose_hand_does_not_load():
    log, hand = [], load_registry().build_hand("allegro")

    class Refusing(_Backend):
        def load_hand(self, hand, floating):
            raise SimulationError("double: no such hand")

    scenes = TrialScenes(lambda name, cfg: Refusing(log), "sapien", SceneConfig(), hand)
    with pytest.raises(SimulationError, match="no such hand"), scenes.open():
        pass
    assert log == [("close", log[0][1])] and scenes.seconds == 0.0  # closed, and no setup time counted
