"""Collision-aware refinement and the pre-grasp: pure checks, a fake backend for error paths, real engines.

The grasps come from the foundation's sim check (``grasp_start_pose`` + ``closed_pose``), not from the
other Stage 1 steps, so these tests stand alone. ``test_synthesis_validate.py`` reuses the helpers.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from ges_core.errors import ArrayError, ConfigError, SimulationError, SynthesisError
from ges_core.kinematics import HandKinematics
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig, SimBackend
from ges_core.sim_check import grasp_start_pose
from ges_core.synthesis.physics.pregrasp import THUMB_KEEP, PregraspConfig, open_joint_mask, pregrasp
from ges_core.synthesis.physics.refine import RefineConfig, creep_direction, refine_grasp, refine_verdict
from ges_core.synthesis.physics.scene import TOUCH_SEPARATION, closing_direction, hand_contacts, stage_scene
from ges_core.synthesis.types import Grasp, RefinedGrasp

REGISTRY = load_registry(autoload=False)
HANDS = tuple(REGISTRY.names("hand"))
SIMS = tuple(REGISTRY.names("sim"))
BOX_HALF_EXTENTS = (0.025, 0.035, 0.05)
"""The sim check's default box: 5 x 7 x 10 cm, fingers close across its 5 cm side."""
DOWN = np.array([0.0, 0.0, -1.0])
"""Approach direction of the palm-down grasps below, object frame."""


def box_object():
    """The 0.105 kg box every test grasps (resting frame: bottom face at z = 0)."""
    return box_asset(BOX_HALF_EXTENTS, density=300.0, object_id="test/refine_box")


def top_grasp(hand, height: float = 0.07, closure: float = 0.5, shift=(0.0, 0.0)) -> Grasp:
    """Palm-down grasp of the test box: closed fingertips centred at (shift, height), q = closed_pose(closure).

    closure 0.5 is the sim check's geometry made gentler: at 0.9 the Allegro palm sits 38 mm inside
    the box; at 0.5 the open hand clears it and index, middle and thumb close on its sides.
    """
    centre = np.array([shift[0], shift[1], height])
    d = hand.description
    return Grasp(hand=hand.name, wrist_pose=grasp_start_pose(hand, centre, closure), q=d.closed_pose(closure))


@pytest.fixture(scope="module")
def allegro():
    return REGISTRY.build_hand("allegro")


class ExplodingBackend(SimBackend):
    """A backend double: does nothing, reads zeros and blows up env 0 once stepped past ``explode_after``.

    Only the engine hooks are written here; the core (``ges_core.sim.SimBackend``) checks arguments and
    raises the SimulationError.
    """

    name = "exploding"
    blowup_hint = "the state blew up"

    def __init__(self, config: SceneConfig | None = None, *, explode_after: int = 0) -> None:
        super().__init__(config or SceneConfig())
        self.explode_after, self.steps, self.k = explode_after, 0, 0

    def _load_hand(self, hand, floating):
        self.k = hand.description.num_joints

    def _load_object(self, obj, ids, fixed):
        pass

    def _rest_height(self, obj, env_id):
        return 0.0

    def _set_joint_targets(self, q):
        pass

    def _set_drive_limits(self, limits):
        pass

    def _set_wrist_targets(self, coords):
        pass

    def _wrist_rotation_targets(self):
        return np.zeros((self.num_envs, 3))

    def _set_hand_state(self, q, base, ids):
        pass

    def _set_object_pose(self, pose, ids):
        pass

    def _step(self, n):
        self.steps += n
        return {0: "exploding env 0: non-finite object velocity (nan)"} if self.steps > self.explode_after else {}

    def _joint_state(self):
        return np.zeros((self.num_envs, self.k)), np.zeros((self.num_envs, self.k))

    def _wrist_pose(self):
        return np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (self.num_envs, 1))

    def _link_poses(self, links):
        return np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (self.num_envs, len(links), 1))

    def _contact_forces(self, links, partner):
        return np.zeros((self.num_envs, len(links), 3))

    def _object_pose(self):
        return self._wrist_pose()

    def _contact_pairs(self, env_id):
        return []

    def _close(self):
        pass


# -- pre-grasp (pure) -------------------------------------------------------------------------
def test_pregrasp_backs_off_along_the_approach_and_keeps_the_rotation(allegro):
    grasp = top_grasp(allegro)
    approach = np.array([1.0, 2.0, -2.0])  # not unit: pregrasp normalizes it
    pre = pregrasp(allegro, grasp, approach)
    np.testing.assert_allclose(pre.wrist_pose[:3], grasp.wrist_pose[:3] - 0.02 * approach / 3.0, atol=1e-12)
    np.testing.assert_allclose(pre.wrist_pose[3:], grasp.wrist_pose[3:])
    assert pre.meta["approach"] == pytest.approx((approach / 3.0).tolist())


@pytest.mark.parametrize("hand_name", HANDS)
def test_pregrasp_opens_the_fingers_but_keeps_thumb_opposition_and_wrist(hand_name):
    """opening="open_pose" (the default is "retract": tests/test_synthesis_squeeze.py)."""
    hand = REGISTRY.build_hand(hand_name)
    d = hand.description
    grasp = top_grasp(hand, closure=0.7)
    pre = pregrasp(hand, grasp, DOWN, PregraspConfig(opening="open_pose"))
    thumb = d.finger_for_slot("thumb")
    finger_joints = {j for f in d.fingers for j in f.joints}
    for k, name in enumerate(d.joint_names):
        # the thumb's first two joints (rotation, abduction: its opposition); Shadow's wrist joints
        kept = name in thumb.joints[:THUMB_KEEP] or name not in finger_joints
        assert pre.q[k] == pytest.approx(grasp.q[k] if kept else d.open_pose[k]), name
    # independent check with forward kinematics: the opened fingertips spread away from the thumb tip
    kin = HandKinematics.from_hand(hand)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
    tips = kin.points(torch.as_tensor(np.stack([grasp.q, pre.q])), list(d.tip_links), offsets).numpy()
    i = [f.slot for f in d.fingers].index("thumb")
    spread = np.linalg.norm(np.delete(tips, i, axis=1) - tips[:, i : i + 1], axis=-1).mean(axis=1)
    assert spread[1] > spread[0] + 0.01


def test_pregrasp_half_open_respects_couplings():
    shadow = REGISTRY.build_hand("shadow")
    d = shadow.description
    grasp = top_grasp(shadow, closure=0.8)
    pre = pregrasp(shadow, grasp, DOWN, PregraspConfig(opening="open_pose", open_fraction=0.5, backoff=0.0))
    np.testing.assert_allclose(pre.wrist_pose, grasp.wrist_pose)
    assert d.couplings, "the Shadow hand declares its tendon couplings"
    for c in d.couplings:
        follower, leader = d.joint_index([c.follower, c.leader])
        assert pre.q[follower] == pytest.approx(min(c.ratio * pre.q[leader], d.joint_limits[follower][1]))
    mask, open_q = open_joint_mask(d, thumb_keep=1), np.asarray(d.open_pose)
    assert np.all(np.abs(pre.q - open_q)[mask] <= np.abs(grasp.q - open_q)[mask] + 1e-12)


@pytest.mark.parametrize(
    ("change", "error", "message"),
    [
        ({"approach": np.zeros(3)}, ArrayError, "pregrasp: approach is a zero vector"),
        ({"approach": np.array([0.0, np.nan, 1.0])}, ArrayError, "pregrasp: approach holds NaN or inf"),
        ({"hand": "shadow"}, ConfigError, "pregrasp: bad grasp: it is for hand 'shadow', not 'allegro'"),
        ({"q": np.zeros(3)}, ArrayError, "pregrasp: grasp q has shape (3,), expected (16,)"),
        ({"q": np.full(16, np.nan)}, ArrayError, "pregrasp: grasp q holds NaN or inf"),
        ({"wrist_pose": np.zeros(7)}, ArrayError, "pregrasp: grasp wrist_pose has a zero quaternion"),
        ({"wrist_pose": np.zeros((4, 4))}, ArrayError, "pregrasp: grasp wrist_pose has shape (4, 4), expected (7,)"),
    ],
)
def test_pregrasp_rejects_bad_input(allegro, change, error, message):
    grasp = top_grasp(allegro)
    approach = change.pop("approach", DOWN)
    fields = {"hand": grasp.hand, "wrist_pose": grasp.wrist_pose, "q": grasp.q, **change}
    with pytest.raises(error) as info:
        pregrasp(allegro, Grasp(**fields), approach)
    assert message in str(info.value)


# -- frames (pure) ----------------------------------------------------------------------------
@pytest.mark.parametrize("hand_name", ["allegro", "shadow"])
def test_creep_moves_every_fingertip_toward_what_it_opposes(hand_name):
    """Finite differences through forward kinematics (not the Jacobian the creep is built from): a small step
    along the creep brings each fingertip closer to its aim (thumb: the other tips' mean; others: the thumb),
    and each finger's largest joint change is the overshoot."""
    hand = REGISTRY.build_hand(hand_name)
    d = hand.description
    q = d.apply_couplings(d.closed_pose(0.5))
    push = creep_direction(hand, q, 0.1)
    kin = HandKinematics.from_hand(hand)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
    thumb = [f.name for f in d.fingers].index(d.finger_for_slot("thumb").name)

    def gaps(joints: np.ndarray) -> np.ndarray:
        tips = kin.points(torch.as_tensor(joints)[None], list(d.tip_links), offsets)[0].numpy()
        aims = np.repeat(tips[thumb][None], len(tips), axis=0)
        aims[thumb] = np.delete(tips, thumb, axis=0).mean(axis=0)
        return np.linalg.norm(aims - tips, axis=1)

    closer = gaps(q) - gaps(q + 1e-3 * push)
    for f, finger in enumerate(d.fingers):
        idx = d.joint_index(finger.joints)
        assert np.abs(push[idx]).max() == pytest.approx(0.1), finger.name
        assert closer[f] > 0, (finger.name, closer)


# -- refine_verdict and error paths (no engine) -----------------------------------------------
@pytest.mark.parametrize(
    ("depth", "table", "frozen", "verdict"),
    [
        (0.001, False, ("index", "thumb"), "ok"),
        (0.010, False, ("index", "thumb"), "penetration"),
        (0.001, True, ("index", "thumb"), "table_contact"),
        (0.001, False, ("index", "middle"), "few_contacts"),  # no thumb
        (0.001, False, ("thumb",), "few_contacts"),
    ],
)
def test_refine_verdict(allegro, depth, table, frozen, verdict):
    refined = RefinedGrasp(grasp=top_grasp(allegro), max_penetration=depth, table_contact=table, frozen=frozen)
    assert refine_verdict(refined, allegro) == verdict


@pytest.mark.parametrize(
    ("shift", "turn", "verdict"),
    [(0.0, 0.0, "ok"), (0.019, 14.9, "ok"), (0.021, 0.0, "object_moved"), (0.0, 15.1, "object_moved")],
)
def test_refine_verdict_rejects_an_object_moved_by_the_close(allegro, shift, turn, verdict):
    grasp = top_grasp(allegro)
    meta = {"touching_fingers": ("index", "thumb"), "object_shift": shift, "object_turn_deg": turn}
    moved = Grasp(hand=grasp.hand, wrist_pose=grasp.wrist_pose, q=grasp.q, meta=meta)
    refined = RefinedGrasp(grasp=moved, max_penetration=0.0, table_contact=False, frozen=())
    assert refine_verdict(refined, allegro) == verdict


def test_refine_verdict_counts_tips_that_touch_without_freezing(allegro):
    """A tip that reaches its retargeted contact exactly touches with ~0 N and is never frozen."""
    grasp = top_grasp(allegro)
    touching = Grasp(
        hand=grasp.hand, wrist_pose=grasp.wrist_pose, q=grasp.q, meta={"touching_fingers": ("index", "thumb")}
    )
    assert (
        refine_verdict(RefinedGrasp(grasp=touching, max_penetration=0.0, table_contact=False, frozen=()), allegro)
        == "ok"
    )


def test_refinement_blow_up_becomes_a_synthesis_error(allegro):
    no_rest_check = RefineConfig(rest_steps=0)
    with pytest.raises(SynthesisError) as info:
        refine_grasp(ExplodingBackend(explode_after=3), allegro, box_object(), top_grasp(allegro), no_rest_check)
    assert info.value.reason == "unstable"
    assert "exploding blew up closing hand 'allegro' on object 'test/refine_box'" in str(info.value)
    assert "non-finite object velocity" in str(info.value)
    # the resting check (on by default) steps first: a blow-up there is 'unstable' too
    with pytest.raises(SynthesisError) as info:
        refine_grasp(ExplodingBackend(explode_after=3), allegro, box_object(), top_grasp(allegro))
    assert info.value.reason == "unstable"
    assert "exploding blew up settling 'test/refine_box'" in str(info.value)


def test_scene_needs_one_env(allegro):
    with pytest.raises(ConfigError) as info:
        stage_scene(ExplodingBackend(SceneConfig(num_envs=2)), allegro, box_object())
    assert "num_envs=2; build it with SceneConfig(num_envs=1)" in str(info.value)


def test_scene_keeps_one_hand_per_backend(allegro):
    sim = ExplodingBackend()
    stage_scene(sim, allegro, box_object())
    stage_scene(sim, allegro, box_object())  # the same hand again: fine, loaded once
    with pytest.raises(SimulationError) as info:
        stage_scene(sim, REGISTRY.build_hand("shadow"), box_object())
    assert "already holds hand 'allegro'; build a new backend for hand 'shadow'" in str(info.value)


# -- real engines -----------------------------------------------------------------------------
def _shift(refined: RefinedGrasp) -> float:
    """How far the object's origin moved during refinement, m."""
    return float(np.linalg.norm(refined.grasp.meta["object_pose_after_refine"][:2]))


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_refinement_freezes_fingers_on_contact(allegro, sim_name):
    d, config = allegro.description, RefineConfig()
    grasp = top_grasp(allegro)
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        refined = refine_grasp(sim, allegro, box_object(), grasp, config)
        start = time.perf_counter()
        again = refine_grasp(sim, allegro, box_object(), grasp, config)
        ms = (time.perf_counter() - start) * 1e3
    print(f"\n{sim_name}: refinement {ms:.0f} ms, {refined.grasp.meta['refine_steps']} steps, frozen {refined.frozen}")
    assert refine_verdict(refined, allegro, config) == "ok", refined
    assert {"thumb", "index"} <= set(refined.frozen) <= set(refined.grasp.meta["touching_fingers"])
    assert refined.max_penetration < 0.002 and not refined.table_contact
    assert refined.grasp.meta["refine_steps"] < config.max_steps  # stopped: every finger frozen or settled
    goal = d.apply_couplings(grasp.q + creep_direction(allegro, grasp.q, config.overshoot))
    for finger in d.fingers:  # frozen fingers stopped short of the goal, free ones reached it
        idx = d.joint_index(finger.joints)
        gap = np.abs(refined.grasp.q[idx] - goal[idx]).max()
        reached = gap < 2 * config.settle_tolerance  # measured: frozen fingers stop 0.09-0.26 rad short
        assert reached != (finger.name in refined.frozen), (finger.name, gap)
    # the wrist drive held the base at the grasp pose (object frame in and out)
    np.testing.assert_allclose(refined.grasp.wrist_pose[:3], grasp.wrist_pose[:3], atol=3e-3)
    # a reused backend gives the same answer as a fresh one
    np.testing.assert_allclose(again.grasp.q, refined.grasp.q, atol=1e-6)
    assert again.frozen == refined.frozen


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_freezing_keeps_the_object_in_place(allegro, sim_name):
    """With a free object, the same closing with freezing switched off (gamma huge) shoves the box around."""
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        frozen = refine_grasp(sim, allegro, box_object(), top_grasp(allegro), RefineConfig(fix_object=False))
        pushing = refine_grasp(
            sim, allegro, box_object(), top_grasp(allegro), RefineConfig(gamma=1e9, fix_object=False)
        )
        rest = stage_scene(sim, allegro, box_object())  # where the box starts: loaded at rest again
    for refined in (frozen, pushing):  # the recorded displacement against the two poses, read independently
        after = np.asarray(refined.grasp.meta["object_pose_after_refine"])
        assert refined.grasp.meta["object_shift"] == pytest.approx(np.linalg.norm(after[:3] - rest[:3]), abs=1e-6)
    assert pushing.grasp.meta["object_turn_deg"] > frozen.grasp.meta["object_turn_deg"]
    assert pushing.frozen == ()
    assert _shift(frozen) < 0.002
    assert _shift(pushing) > 0.005 and _shift(pushing) > 3 * _shift(frozen)


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_fixed_object_is_not_moved_even_without_freezing(allegro, sim_name):
    """fix_object (default): the object stays at rest even when fingers never freeze and push on (gamma huge)."""
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        pushing = refine_grasp(sim, allegro, box_object(), top_grasp(allegro), RefineConfig(gamma=1e9))
        rest = stage_scene(sim, allegro, box_object())
    after = np.asarray(pushing.grasp.meta["object_pose_after_refine"])
    np.testing.assert_allclose(after, rest, atol=1e-6)
    assert pushing.grasp.meta["object_shift"] < 1e-6 and pushing.grasp.meta["object_turn_deg"] < 1e-3
    assert len(pushing.grasp.meta["touching_fingers"]) >= 2  # the tips reached it and pushed


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_creep_brings_fingertips_that_stop_short_onto_the_object(allegro, sim_name):
    """A retargeted pose a little short of the surface: without the creep no tip ever touches. Short along the
    closing path from the open pose, so the close starts there (from the retracted hand, the default, PyBullet's
    index reached the box at this pose: short along one path is not along every other)."""
    d = allegro.description
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        touching = refine_grasp(sim, allegro, box_object(), top_grasp(allegro), RefineConfig(overshoot=0.0)).grasp
        q_open = np.where(open_joint_mask(d, 1), np.asarray(d.open_pose), touching.q)
        q_short = touching.q - 0.05 * closing_direction(q_open, touching.q)  # each joint 0.05 rad more open
        short = Grasp(hand=touching.hand, wrist_pose=touching.wrist_pose, q=q_short)
        stops = refine_grasp(sim, allegro, box_object(), short, RefineConfig(overshoot=0.0, start="open_pose"))
        creeps = refine_grasp(sim, allegro, box_object(), short, RefineConfig(start="open_pose"))
    assert stops.grasp.meta["touching_fingers"] == () and refine_verdict(stops, allegro) == "few_contacts"
    assert {"index", "thumb"} <= set(creeps.frozen) and refine_verdict(creeps, allegro) == "ok"


def _spy_hand_states(sim: SimBackend) -> list[np.ndarray]:
    """The joints (B, K) of every ``sim.set_hand_state`` call from now on (the backend still runs them)."""
    given, set_state = [], sim.set_hand_state

    def spy(q, *args, **kwargs):
        given.append(np.array(q))
        return set_state(q, *args, **kwargs)

    sim.set_hand_state = spy
    return given


@pytest.mark.sim
def test_the_close_starts_from_the_retracted_hand_by_default(allegro):
    """refine_grasp puts the hand first at ``retract_joints`` of the grasp (the pre-grasp's opened hand), or with
    ``start="open_pose"`` at the open pose but the thumb's kept joints; a spy on the real backend reads the state it
    is given."""
    from ges_core.synthesis.physics.squeeze import retract_joints

    d, grasp = allegro.description, top_grasp(allegro)
    q = d.apply_couplings(grasp.q)
    expected = {
        "retract": retract_joints(allegro, q, travel=RefineConfig().start_retract),
        "open_pose": np.where(open_joint_mask(d, THUMB_KEEP), np.asarray(d.open_pose), q),
    }
    assert RefineConfig().start == "retract"
    for start, q_start in expected.items():
        with REGISTRY.build_sim("sapien", SceneConfig()) as sim:
            given = _spy_hand_states(sim)
            refine_grasp(sim, allegro, box_object(), grasp, RefineConfig(start=start, rest_steps=0))
        assert len(given) == 1, len(given)  # staging puts the object only; the close moves the hand by drives
        np.testing.assert_allclose(given[0][0], q_start, atol=1e-12, err_msg=start)
    assert np.abs(expected["retract"] - expected["open_pose"]).max() > 0.1  # two different hands


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_hand_beside_the_object_freezes_nothing(allegro, sim_name):
    grasp = top_grasp(allegro, shift=(0.0, 0.15))
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        refined = refine_grasp(sim, allegro, box_object(), grasp)
    assert refined.frozen == () == refined.grasp.meta["touching_fingers"]
    assert refine_verdict(refined, allegro) == "few_contacts"
    assert refined.max_penetration == 0.0 and not refined.table_contact
    config, d = RefineConfig(), allegro.description
    goal = d.apply_couplings(grasp.q + creep_direction(allegro, grasp.q, config.overshoot))  # all free: all reach it
    np.testing.assert_allclose(refined.grasp.q, goal, atol=2 * config.settle_tolerance)


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
@pytest.mark.parametrize("hand_name", HANDS)
def test_refinement_touches_without_penetrating_for_every_hand(hand_name, sim_name):
    hand = REGISTRY.build_hand(hand_name)
    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        refined = refine_grasp(sim, hand, box_object(), top_grasp(hand, height=0.08))
    print(f"\n{hand_name} in {sim_name}: frozen {refined.frozen}, {refined.max_penetration * 1e3:.2f} mm")
    assert len(refined.frozen) >= 2
    assert refined.max_penetration < 0.003 and not refined.table_contact


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_table_separation_decides_whether_a_hand_just_above_the_table_touches(allegro, sim_name):
    """The open hand lowered until the engine reports it a fraction of a millimetre above the table with no force:
    it touches the table by the default rule (closer than TOUCH_SEPARATION) and not with ``table_separation=None``;
    pressed 3 mm further down it touches by both (its force above ``table_force``)."""
    d, config = allegro.description, RefineConfig()
    q = d.apply_couplings(d.open_pose)
    above = top_grasp(allegro, height=0.12).wrist_pose
    away = box_asset((0.02, 0.02, 0.02), density=300.0, object_id="test/away_box")

    def held_at(sim, drop: float):
        base = above.copy()
        base[2] -= drop
        sim.set_hand_state(q[None], base[None])
        sim.set_joint_targets(q[None])
        sim.set_wrist_targets(base[None])
        sim.step(1)
        pairs = [p for p in sim.contact_pairs(0) if {p.body_a, p.body_b} == {"hand", "table"}]
        gap = min((p.separation for p in pairs), default=np.inf)
        force = max((p.force for p in pairs), default=0.0)
        return gap, force

    with REGISTRY.build_sim(sim_name, SceneConfig()) as sim:
        stage_scene(sim, allegro, away)
        sim.set_object_pose(np.array([[0.5, 0.5, 0.02, 1.0, 0.0, 0.0, 0.0]]))
        assert held_at(sim, 0.0)[0] > TOUCH_SEPARATION  # the start is clear of the table
        lo, hi = 0.0, 0.2  # drop (m): clear at lo; at hi far into the table
        for _ in range(40):  # bisect for a drop that leaves a gap of 0.1-0.4 mm
            mid = 0.5 * (lo + hi)
            gap, force = held_at(sim, mid)
            if 1e-4 < gap < 4e-4 and force == 0.0:
                break
            lo, hi = (mid, hi) if gap >= 4e-4 else (lo, mid)
        else:
            pytest.fail(f"{sim_name}: no drop left the hand 0.1-0.4 mm above the table with no force")
        default = hand_contacts(sim, config.table_force, config.table_separation).table
        force_only = hand_contacts(sim, config.table_force, None).table
        assert (default, force_only) == (True, False)
        gap, force = held_at(sim, mid + 0.003)
        assert force > config.table_force
        assert hand_contacts(sim, config.table_force, None).table
