"""Physics validation: the verdict rules, the squeeze, agreement, and real lifts with negative controls.

Every grasp is validated in every simulator once (module fixture); the tests then check the good
grasps succeed, each negative control fails for the right reason, and the simulators agree.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_synthesis_refine import DOWN, REGISTRY, SIMS, ExplodingBackend, box_object, top_grasp

from ges_core.config import parse_model
from ges_core.errors import ConfigError
from ges_core.kinematics import HandKinematics
from ges_core.sim import SceneConfig
from ges_core.synthesis.physics.pregrasp import pregrasp
from ges_core.synthesis.physics.refine import refine_grasp, refine_verdict
from ges_core.synthesis.physics.scene import tip_rule
from ges_core.synthesis.physics.squeeze import press_directions, squeeze_targets
from ges_core.synthesis.physics.validate import (
    HoldRecord,
    ValidateConfig,
    agreement,
    classify,
    tips_needed,
    validate_grasp,
)
from ges_core.synthesis.types import Grasp, ValidationResult

CONFIG = ValidateConfig()


@pytest.fixture(scope="module")
def allegro():
    return REGISTRY.build_hand("allegro")


# -- verdict rules (pure) ---------------------------------------------------------------------
def _record(touched=True, lifted=True, high=1.0, tips=1.0, n=200) -> HoldRecord:
    """A run whose object was high for the first ``high`` share of the hold and tip-held for ``tips``."""
    steps = np.arange(n)
    return HoldRecord(touched, lifted, steps < high * n, steps < tips * n)


@pytest.mark.parametrize(
    ("record", "reason"),
    [
        (_record(), "success"),
        (_record(tips=0.9), "success"),  # a chattering contact now and then is tolerated
        (_record(tips=0.85), "palm_only"),
        (_record(tips=0.0), "palm_only"),
        (_record(touched=False, tips=0.0), "palm_only"),  # carried without any fingertip
        (_record(high=0.5), "dropped"),
        (_record(lifted=False, high=0.0, tips=0.0), "not_lifted"),
        (_record(touched=False, lifted=False, high=0.0, tips=0.0), "no_contact"),
    ],
)
def test_classify(record, reason):
    assert classify(record, CONFIG) == reason


def test_tip_rule_needs_two_tips_with_the_thumb():
    forces = np.array([0.0, 0.3, 0.3, 0.0])  # index, middle, ring, thumb (Allegro order)
    assert not tip_rule(forces, thumb=3, min_force=0.05, min_tips=2, require_thumb=True)
    assert tip_rule(forces, thumb=3, min_force=0.05, min_tips=2, require_thumb=False)
    forces[3] = 0.06
    assert tip_rule(forces, thumb=3, min_force=0.05, min_tips=2, require_thumb=True)
    assert not tip_rule(forces, thumb=3, min_force=0.05, min_tips=4, require_thumb=True)


@pytest.mark.parametrize("name", ["allegro", "shadow"])
def test_squeeze_presses_each_fingertip_toward_what_it_opposes(name):
    """First-order tip motion of the squeeze, through an independent numeric FK difference, points along the press."""
    hand = REGISTRY.build_hand(name)
    d = hand.description
    q_grasp = d.apply_couplings(d.closed_pose(0.5))
    close = squeeze_targets(hand, q_grasp, force=5.0, min_squeeze=0.0, max_squeeze=10.0)
    kin = HandKinematics.from_hand(hand)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
    tips = kin.points(
        torch.as_tensor(np.stack([q_grasp, q_grasp + 1e-4 * (close - q_grasp)])), list(d.tip_links), offsets
    )
    motion = (tips[1] - tips[0]).numpy()
    press = press_directions(d, tips[0].numpy())
    cos = np.sum(motion * press, axis=1) / np.linalg.norm(motion, axis=1)
    assert np.all(cos > 0.0), f"{name}: a fingertip moves away from what it opposes: cos {cos}"
    no_finger = [i for i, j in enumerate(d.joint_names) if all(j not in f.joints for f in d.fingers)]
    np.testing.assert_array_equal(close[no_finger], q_grasp[no_finger])  # Shadow's wrist joints: not pushed


def test_squeeze_floor_and_cap(allegro):
    d = allegro.description
    q_grasp = d.apply_couplings(d.closed_pose(0.5))
    # Allegro's Kp = 400 N·m/rad: 5 N is ~1 mrad, so the largest angle is raised to the 0.05 rad floor
    close = squeeze_targets(allegro, q_grasp, force=5.0, min_squeeze=0.05, max_squeeze=0.6)
    assert np.abs(close - q_grasp).max() == pytest.approx(0.05)
    shadow = REGISTRY.build_hand("shadow")
    sd = shadow.description
    q_grasp = sd.apply_couplings(sd.closed_pose(0.5))
    close = squeeze_targets(shadow, q_grasp, force=500.0, min_squeeze=0.0, max_squeeze=0.3)
    leaders = [i for i, j in enumerate(sd.joint_names) if j not in {c.follower for c in sd.couplings}]
    assert np.abs(close - q_grasp)[leaders].max() == pytest.approx(0.3)  # Kp = 1: 500 N asks for far more
    ffj1 = sd.joint_index(["FFJ1"])[0]
    assert close[ffj1 + 1] == pytest.approx(min(1.141844 * close[ffj1], 1.571), abs=1e-4)  # FFJ0 follows FFJ1


def test_a_thumb_force_scales_the_thumbs_squeeze_and_its_cap_alone():
    """``squeeze_targets(thumb_force=...)``: the thumb's extra angles grow by thumb_force / force and so does its
    joints' cap; every other joint gets exactly the targets of the plain squeeze. (1 N and 2 N: small enough that no
    thumb joint reaches its limit, where the targets are clipped.)"""
    shadow = REGISTRY.build_hand("shadow")
    d = shadow.description
    q = d.apply_couplings(d.closed_pose(0.5))
    thumb = d.joint_index(d.finger_for_slot("thumb").joints)
    others = np.setdiff1d(np.arange(d.num_joints), thumb)
    plain = squeeze_targets(shadow, q, force=1.0, min_squeeze=0.0, max_squeeze=10.0)
    double = squeeze_targets(shadow, q, force=1.0, min_squeeze=0.0, max_squeeze=10.0, thumb_force=2.0)
    np.testing.assert_array_equal(double[others], plain[others])
    np.testing.assert_allclose(double[thumb] - q[thumb], 2.0 * (plain[thumb] - q[thumb]), rtol=1e-9)
    assert np.abs(plain[thumb] - q[thumb]).max() > 0.01  # the thumb is pushed at all
    capped = squeeze_targets(shadow, q, force=7.0, min_squeeze=0.0, max_squeeze=0.05, thumb_force=14.0)
    leaders = [i for i in others if d.joint_names[i] not in {c.follower for c in d.couplings}]
    assert np.abs(capped - q)[thumb].max() == pytest.approx(0.1)  # the thumb's cap doubled with its force
    assert np.abs(capped - q)[leaders].max() == pytest.approx(0.05)
    same = squeeze_targets(shadow, q, force=7.0, min_squeeze=0.0, max_squeeze=0.05, thumb_force=7.0)
    np.testing.assert_array_equal(same, squeeze_targets(shadow, q, force=7.0, min_squeeze=0.0, max_squeeze=0.05))


@pytest.mark.parametrize(
    ("mass", "expected"),
    [(0.0, 7.0), (0.2, 7.0), (0.4, 9.8), (0.5, 12.25), (0.6, 14.0), (5.0, 14.0)],
)
def test_the_thumbs_force_follows_the_objects_mass_between_the_squeeze_and_its_cap(mass, expected):
    config = ValidateConfig(squeeze_force=7.0, thumb_force_per_kg=24.5, thumb_max_scale=2.0)
    assert config.thumb_force(mass) == pytest.approx(expected)
    assert ValidateConfig(squeeze_force=7.0).thumb_force(mass) == 7.0  # off by default: the thumb asks what all ask


def test_the_thumb_settings_are_stored_only_when_set():
    """Added after datasets were written: a config that leaves them at their defaults stores what it stored before,
    so those datasets still match; one that sets them stores them."""
    from ges_core.config import stored_dump

    assert not {"thumb_force_per_kg", "thumb_max_scale"} & set(stored_dump(ValidateConfig()))
    assert stored_dump(ValidateConfig(thumb_force_per_kg=24.5))["thumb_force_per_kg"] == 24.5


def test_press_directions_oppose_the_thumb():
    d = REGISTRY.build_hand("allegro").description
    tips = np.zeros((4, 3))
    thumb = [f.name for f in d.fingers].index(d.finger_for_slot("thumb").name)
    tips[:, 0] = 0.05
    tips[thumb] = [-0.05, 0.0, 0.0]
    u = press_directions(d, tips)
    np.testing.assert_allclose(u[thumb], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.delete(u, thumb, axis=0), np.tile([-1.0, 0.0, 0.0], (3, 1)))


def test_agreement():
    ok, bad = ValidationResult(True, "success"), ValidationResult(False, "no_contact")
    assert agreement([ok, bad, ok, bad], [ok, bad, bad, bad]) == 0.75
    assert agreement([ok], [ok]) == 1.0
    with pytest.raises(ConfigError) as info:
        agreement([ok, bad], [ok])
    assert "equally long, non-empty result lists" in str(info.value) and "got 2 and 1" in str(info.value)
    with pytest.raises(ConfigError):
        agreement([], [])


def test_blow_up_is_recorded_as_unstable_not_raised(allegro):
    grasp = top_grasp(allegro)
    sim = ExplodingBackend(explode_after=100)  # blows up while closing
    result = validate_grasp(sim, allegro, box_object(), grasp, pregrasp(allegro, grasp, DOWN))
    assert not result.success and result.reason == "unstable"
    assert result.flags == {"reached_grasp": False, "fingertips_touching": False, "lifted": False, "held": False}
    assert sim.steps == 101


def test_a_nan_command_inside_the_run_is_unstable_not_raised(allegro, monkeypatch):
    """A closing target computed as NaN (from a blown-up state) is refused at the backend's boundary
    (ArrayError); validation records it as ``unstable`` like a blow-up, so one perturbation trial cannot
    take the grasp's other verdicts with it."""
    grasp = top_grasp(allegro)
    monkeypatch.setattr(
        "ges_core.synthesis.physics.validate.squeeze_targets", lambda hand, q, **kw: np.full_like(q, np.nan)
    )
    sim = ExplodingBackend(explode_after=10**6)
    result = validate_grasp(sim, allegro, box_object(), grasp, pregrasp(allegro, grasp, DOWN))
    assert not result.success and result.reason == "unstable"
    assert sim.steps == ValidateConfig().approach_steps  # stopped at the first closing target


@pytest.mark.parametrize(("squeeze_mass", "thumb"), [(None, 10.0), (0.1, 5.0), (0.3, 7.35)])
def test_validation_sizes_the_thumbs_squeeze_for_the_objects_mass_or_the_one_given(
    allegro, monkeypatch, squeeze_mass, thumb
):
    """validate_grasp hands ``squeeze_targets`` the thumb force of ``ValidateConfig.thumb_force``: for the object's
    own mass (0.6 kg here: 24.5 N/kg is capped at twice the 5 N), or for ``squeeze_mass`` when given (what a
    perturbation trial passes). The closing target is made NaN to end the run there (reason ``unstable``)."""
    from dataclasses import replace

    asked = []

    def nan_targets(hand, q, **kw):
        asked.append(kw)
        return np.full_like(q, np.nan)

    monkeypatch.setattr("ges_core.synthesis.physics.validate.squeeze_targets", nan_targets)
    grasp = top_grasp(allegro)
    config = ValidateConfig(thumb_force_per_kg=24.5)
    obj = replace(box_object(), mass=0.6)
    pre = pregrasp(allegro, grasp, DOWN)
    result = validate_grasp(
        ExplodingBackend(explode_after=10**6), allegro, obj, grasp, pre, config, squeeze_mass=squeeze_mass
    )
    assert result.reason == "unstable"
    assert [(a["force"], a["thumb_force"]) for a in asked] == [(5.0, pytest.approx(thumb))]


def test_validation_rejects_a_grasp_of_another_hand(allegro):
    grasp = top_grasp(allegro)
    foreign = Grasp(hand="shadow", wrist_pose=grasp.wrist_pose, q=grasp.q)
    with pytest.raises(ConfigError) as info:
        validate_grasp(ExplodingBackend(), allegro, box_object(), grasp, foreign)
    assert "validate_grasp pregrasp: bad grasp: it is for hand 'shadow', not 'allegro'" in str(info.value)


# -- real engines -----------------------------------------------------------------------------
def _cases(hand) -> dict[str, tuple[Grasp, bool]]:
    """name -> (grasp, refine it first?). Two good grasps and three negative controls."""
    d = hand.description
    good = top_grasp(hand, height=0.07)
    open_q = np.asarray(d.open_pose)
    index = d.joint_index(d.finger_for_slot("index").joints)
    single = open_q.copy()
    single[index] = good.q[index]  # only the index finger flexes
    return {
        "good": (good, True),
        "good_high": (top_grasp(hand, height=0.09), True),
        "open_no_closing": (Grasp(hand=hand.name, wrist_pose=good.wrist_pose, q=open_q), False),
        "beside": (top_grasp(hand, height=0.07, shift=(0.0, 0.15)), False),
        "single_finger": (Grasp(hand=hand.name, wrist_pose=good.wrist_pose, q=single), False),
    }


@pytest.fixture(scope="module")
def validated(allegro) -> dict[str, dict[str, ValidationResult]]:
    """sim -> case -> result; good grasps go through refinement first, controls as they are."""
    out: dict[str, dict[str, ValidationResult]] = {}
    for sim_name in SIMS:
        out[sim_name] = {}
        with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
            for name, (grasp, refine) in _cases(allegro).items():
                if refine:
                    refined = refine_grasp(sim, allegro, box_object(), grasp)
                    assert refine_verdict(refined, allegro) == "ok", (sim_name, name, refined)
                    grasp = refined.grasp
                out[sim_name][name] = validate_grasp(sim, allegro, box_object(), grasp, pregrasp(allegro, grasp, DOWN))
    return out


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
@pytest.mark.parametrize("case", ["good", "good_high"])
def test_good_grasps_lift_and_hold(validated, sim_name, case):
    result = validated[sim_name][case]
    print(f"\n{sim_name} {case}: validation {result.seconds * 1e3:.0f} ms")
    assert result.success and result.reason == "success", result
    assert all(result.flags.values()), result.flags


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
@pytest.mark.parametrize(
    ("case", "reasons"),
    [
        ("open_no_closing", {"no_contact", "not_lifted"}),
        ("beside", {"no_contact"}),
        ("single_finger", {"not_lifted", "palm_only", "dropped"}),
    ],
)
def test_negative_controls_fail_for_the_right_reason(validated, sim_name, case, reasons):
    result = validated[sim_name][case]
    print(f"\n{sim_name} {case}: {result.reason} {result.flags}")
    assert not result.success and result.reason in reasons, result
    assert not result.flags["held"]


@pytest.mark.sim
def test_simulators_agree_on_clear_cases(validated):
    names = list(_cases(REGISTRY.build_hand("allegro")))
    a, b = ([validated[s][n] for n in names] for s in SIMS[:2])
    rate = agreement(a, b)
    print(f"\ncross-simulator agreement {SIMS[0]} vs {SIMS[1]} on {len(names)} grasps: {rate:.2f}")
    assert rate >= 0.75


# -- the hold ends once the verdict is settled -------------------------------------------------
class _ScriptedHold:
    """A test double for the hold: the object's height, the fingertip touch and the fingertip rule per step, from
    lists (the rule holds at every step unless given); counts the steps and the steps that read the forces."""

    def __init__(self, heights, touches, rules=None) -> None:
        self.heights, self.touches, self.steps = list(heights), list(touches), 0
        self.rules = list(rules) if rules is not None else [True] * len(self.heights)
        self.touched, self.reads, self.read_last = False, 0, False

    def step(self, *, read: bool = False) -> None:  # the probe's step
        self.touched = self.touched or self.touches[self.steps]
        self.steps += 1
        self.read_last = read
        self.reads += read

    def rule(self) -> bool:
        assert self.read_last, "the rule was asked at a step that did not read the forces"
        return self.rules[self.steps - 1]

    def object_pose(self) -> np.ndarray:  # the backend's, read after each step
        return np.array([[0.0, 0.0, self.heights[self.steps - 1], 1.0, 0.0, 0.0, 0.0]])


@pytest.mark.parametrize(
    ("lifted", "touched_before", "heights", "touches", "reason", "steps"),
    [
        (False, True, [0.0] * 10, [False] * 10, "not_lifted", 0),  # nothing the hold sees can change it
        (False, False, [0.0] * 10, [False] * 3 + [True] * 7, "not_lifted", 4),  # until the first touch
        (False, False, [0.0] * 10, [False] * 10, "no_contact", 10),
        (True, True, [0.2] * 4 + [0.0] * 6, [True] * 10, "dropped", 5),  # the first low step decides
        (True, True, [0.2] * 10, [True] * 10, "success", 10),  # success needs every step
    ],
)
def test_the_hold_stops_once_the_verdict_is_settled(lifted, touched_before, heights, touches, reason, steps):
    from ges_core.synthesis.physics.validate import _hold

    config = ValidateConfig(hold_steps=10)
    verdicts = {}
    for full in (False, True):
        double = _ScriptedHold(heights, touches)
        double.touched = touched_before
        record = _hold(double, double, 0.0, lifted, config, full_hold=full)
        verdicts[full] = (classify(record, config), double.steps)
    assert verdicts[False] == (reason, steps)
    assert verdicts[True] == (reason, 10)  # the full hold: every step, the same verdict


class _ScriptedLift(_ScriptedHold):
    """The lift's test double: the object's height per step (m above its rest), the wrist targets it was given."""

    def __init__(self, heights, touches) -> None:
        super().__init__(heights, touches)
        self.targets = []

    def set_wrist_targets(self, pose) -> None:
        self.targets.append(float(pose[0, 2]))


@pytest.mark.parametrize(
    ("follows", "touched_at", "lost_at"),
    [
        (10, 1, 16),  # follows the target to 0.10, then stays: 0.06 below the rise at step 16 (> 0.055)
        (10, 18, 18),  # long behind when first touched: lost at that step
        (10, None, None),  # never touched: no_contact is not settled by the lift (a later touch would change it)
        (20, 1, None),  # follows the whole lift
    ],
)
def test_the_lift_ends_once_a_touched_object_is_lost(follows, touched_at, lost_at):
    """The target rises 0.01 m per step over 20 steps; the object follows it for ``follows`` steps and stays. The
    lift ends, object lost, at the first step where it was touched and lies more than ``lost_lag`` (0.055 m) below
    the target's rise; with full_hold it runs every step and reports nothing lost."""
    from ges_core.synthesis.physics.validate import _lift

    config = ValidateConfig(lift_steps=20, lift_height=0.2, lost_lag=0.055)
    rises = [0.01 * min(step, follows) for step in range(1, 21)]
    touches = [touched_at is not None and step >= touched_at for step in range(1, 21)]
    goal = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    for full in (False, True):
        double = _ScriptedLift(rises, touches)
        lost = _lift(double, goal, double, 0.0, config, full)
        ends = lost_at if lost_at is not None and not full else 20
        assert (lost, double.steps) == (ends < 20, ends), full
        assert double.targets == pytest.approx([0.01 * step for step in range(1, ends + 1)])


def test_a_lost_lag_within_the_lift_tolerance_is_refused():
    with pytest.raises(ConfigError, match=r"lost_lag \(0.03 m\) must exceed lift_tolerance \(0.03 m\)"):
        parse_model(ValidateConfig, {"lost_lag": 0.03}, where="test")
    assert parse_model(ValidateConfig, {"lost_lag": None}, where="test").lost_lag is None


@pytest.mark.parametrize(
    ("steps", "fraction"), [(200, 0.9), (10, 0.9), (7, 0.5), (3, 1 / 3), (10, 1.0), (200, 0.95), (9, 0.7)]
)
def test_tips_needed_is_where_classify_turns_to_success(steps, fraction):
    """classify's own verdict, with the fingertip rule at the first n of the hold steps: palm_only below
    tips_needed, success from it on."""
    config = ValidateConfig(hold_steps=steps, hold_fraction=fraction)
    needed = tips_needed(config)
    verdicts = [
        classify(HoldRecord(True, True, np.ones(steps, bool), np.arange(steps) < n), config) for n in range(steps + 1)
    ]
    assert verdicts == ["palm_only"] * needed + ["success"] * (steps + 1 - needed)


@pytest.mark.parametrize(
    ("rules", "reason", "reads"),
    [
        ([True] * 10, "success", 9),  # 9 of 10 steps with the rule pass 0.9: the last step is not read
        ([False] + [True] * 9, "success", 10),  # one miss: every step is needed
        ([False, False] + [True] * 8, "palm_only", 2),  # two misses: 0.9 is out of reach, no more reads
        ([True] * 5 + [False] + [True] * 4, "success", 10),
        ([True] * 8 + [False] * 2, "palm_only", 10),  # the second miss at the last step decides
    ],
)
def test_the_hold_reads_the_fingertip_rule_until_its_share_is_decided(rules, reason, reads):
    """The verdict is the one of reading every step (full_hold); the reads stop once the share cannot change
    side of hold_fraction (10 steps, 0.9: 9 steps with the rule needed, a second miss is decisive)."""
    from ges_core.synthesis.physics.validate import _hold

    config = ValidateConfig(hold_steps=10)
    runs = {}
    for full in (False, True):
        double = _ScriptedHold([0.2] * 10, [True] * 10, rules)
        double.touched = True
        record = _hold(double, double, 0.0, True, config, full_hold=full)
        runs[full] = (classify(record, config), double.steps, double.reads)
    assert runs[True] == (reason, 10, 10)
    assert runs[False] == (reason, 10, reads)


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_an_early_verdict_is_the_full_holds_verdict_in_the_engines(allegro, sim_name):
    """The controls that fail (not lifted, dropped) take fewer physics steps and give the full lift and hold's
    verdict and flags (the single finger loses the box during the lift); a grasp that holds runs every step either
    way. Every trial but a ``no_contact`` one reads the fingertip forces at fewer steps than it runs, and gives the
    verdict and flags of reading them at every step."""
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        counted = {"steps": 0}
        step = sim.step

        def counting_step(*args, **kwargs):
            counted["steps"] += 1
            return step(*args, **kwargs)

        sim.step = counting_step
        forces = sim.contact_forces

        def counting_forces(*args, **kwargs):
            counted["reads"] += 1
            return forces(*args, **kwargs)

        counted["reads"] = 0
        sim.contact_forces = counting_forces
        cases = _cases(allegro)
        good = refine_grasp(sim, allegro, box_object(), cases["good"][0]).grasp
        shorter = read_less = lost = 0
        config = ValidateConfig()
        before_hold = config.approach_steps + config.close_steps + config.lift_steps
        for name, grasp in [("good", good), *((n, g) for n, (g, refine) in cases.items() if not refine)]:
            pre = pregrasp(allegro, grasp, DOWN)
            runs = []
            for full in (False, True):
                before, reads_before = counted["steps"], counted["reads"]
                result = validate_grasp(sim, allegro, box_object(), grasp, pre, full_hold=full)
                runs.append((result.reason, result.flags, counted["steps"] - before, counted["reads"] - reads_before))
            (early, early_flags, n_early, reads_early), (full, full_flags, n_full, reads_full) = runs
            print(f"\n{sim_name} {name}: {early} in {n_early} steps, full hold {full} in {n_full}; reads {runs}")
            assert (early, early_flags) == (full, full_flags), (name, runs)
            assert reads_full == n_full  # the reference run reads the fingertip forces at every step
            if early == "no_contact":  # only every step's forces can tell that no fingertip touched
                assert reads_early == n_early, (name, runs)
            else:
                assert reads_early < n_early, (name, runs)
                read_less += 1
            if early in ("not_lifted", "dropped"):
                assert n_early < n_full, (name, runs)
                shorter += 1
                lost += n_early < before_hold  # the lift's own early end: the object lost on the way up
            else:
                assert n_early == n_full, (name, runs)
        assert shorter >= 1  # at least one control was settled before the end of the hold
        assert lost >= 1  # and one (the single finger) was lost during the lift
        assert read_less >= 2  # the good grasp and a control
