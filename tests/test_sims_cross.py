"""Every hand in every simulator, against each other and against pytorch-kinematics.

These run the real engines at small size: the same scene must give the same physics in SAPIEN
and PyBullet, and both must agree with an independent kinematics library.
"""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.lint.checks_physics import check_fk_matches_sims, check_self_collision
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import SimCheckConfig, run_sim_check
from ges_core.urdf import neighbour_link_pairs

HANDS = tuple(load_registry(autoload=False).names("hand"))
"""Every registered built-in hand: each must pass every test below."""
SIMS = tuple(load_registry(autoload=False).names("sim"))
"""Every registered built-in simulator."""

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def registry():
    return load_registry(autoload=False)


def _rest_height(registry, sim_name: str, obj, drop: float) -> np.ndarray:
    with registry.build_sim(sim_name, SceneConfig()) as sim:
        sim.load_object(obj, pose=np.array([0.0, 0.0, drop, 1.0, 0.0, 0.0, 0.0]))
        sim.step(240)
        return sim.object_pose()[0]


@pytest.mark.parametrize("half_extents", [(0.03, 0.02, 0.04), (0.05, 0.05, 0.01)])
def test_dropped_box_rests_at_the_same_height_in_both(registry, half_extents):
    obj = box_asset(half_extents)
    heights = [_rest_height(registry, s, obj, drop=0.1)[2] for s in SIMS]
    for z in heights:  # resting frame: the bottom face is the origin
        assert z == pytest.approx(0.0, abs=2e-3)
    assert max(heights) - min(heights) < 2e-3


@pytest.mark.parametrize("sim_name", SIMS)
@pytest.mark.parametrize("hand_name", HANDS)
def test_hand_closing_on_a_box_makes_fingertip_contacts(registry, hand_name, sim_name):
    hand = registry.build_hand(hand_name)
    config = SimCheckConfig(close_steps=120, lift_steps=0, settle_steps=10)
    with registry.build_sim(sim_name, config.scene) as sim:
        report = run_sim_check(hand, sim, config)
    assert report.touching >= 2, report.format()
    assert np.all(np.isfinite(report.tip_forces))


@pytest.mark.parametrize("sim_name", SIMS)
@pytest.mark.parametrize("hand_name", HANDS)
def test_pytorch_kinematics_matches_the_simulator(registry, hand_name, sim_name):
    """Tip and keypoint link positions agree within 1 mm for random joint values."""
    problems = check_fk_matches_sims(registry.build_hand(hand_name), sim_name, registry.build_sim, samples=6, seed=7)
    assert problems == []


def test_builtins_are_all_there():
    assert {"shadow", "allegro"} <= set(HANDS) and {"sapien", "pybullet"} <= set(SIMS)


@pytest.mark.parametrize("name", HANDS)
def test_every_registered_hand_builds(registry, name):
    hand = registry.build_hand(name)
    assert hand.urdf_path().is_file() and hand.description.num_joints > 0


@pytest.mark.parametrize("name", SIMS)
def test_every_registered_sim_builds_and_closes(registry, name):
    sim = registry.build_sim(name, SceneConfig(num_envs=2))
    assert sim.num_envs == 2
    sim.close()
    sim.close()  # idempotent


# -- self-collision: neighbour pairs excluded, every other pair colliding --------------------------
def _hand_pairs(sim) -> dict[frozenset[str], float]:
    """Deepest separation (m) of every touching hand-hand link pair in env 0."""
    out: dict[frozenset[str], float] = {}
    for c in sim.contact_pairs(0):
        if c.body_a == c.body_b == "hand":
            key = frozenset((c.link_a, c.link_b))
            out[key] = min(out.get(key, np.inf), c.separation)
    return out


@pytest.mark.parametrize("sim_name", SIMS)
def test_shadow_neighbour_links_are_excluded_and_the_rest_collide(registry, sim_name):
    """Open pose: no overlap deeper than 1 mm (palm-thproximal overlapped 15 mm and thproximal-thmiddle
    24 mm while only parent-child pairs were excluded). Index and middle spread toward each other
    (a pair that is no neighbour): their proximal links must still report a contact. The rule of a hand given as a
    URDF, which the Shadow follows with ``self_collision: all``."""
    hand = load_registry(overrides=("settings.hand.shadow.self_collision=all",)).build_hand("shadow")
    d = hand.description
    neighbours = neighbour_link_pairs(hand.urdf_text())
    open_q = np.asarray(d.open_pose)[None]
    lim = d.limits_array
    with registry.build_sim(sim_name, SceneConfig(self_collision=True, gravity=0.0)) as sim:
        sim.load_hand(hand, floating=False)
        sim.set_hand_state(open_q)
        sim.step(1)
        assert {pair: sep for pair, sep in _hand_pairs(sim).items() if sep < -1e-3} == {}
        spread = open_q.copy()
        spread[0, d.joint_names.index("FFJ3")] = lim[d.joint_names.index("FFJ3"), 0]
        spread[0, d.joint_names.index("MFJ3")] = lim[d.joint_names.index("MFJ3"), 1]
        sim.set_hand_state(spread)
        sim.step(1)
        assert _hand_pairs(sim).get(frozenset(("ffproximal", "mfproximal")), 0.0) < -5e-3
        seen: set[frozenset[str]] = set()
        for q in np.random.default_rng(3).uniform(lim[:, 0], lim[:, 1], size=(8, d.num_joints)):
            sim.set_hand_state(q[None])
            sim.step(1)
            seen |= set(_hand_pairs(sim))
        assert seen and not seen & neighbours
    assert check_self_collision(hand, sim_name, registry.build_sim) == []  # `ges hand lint`'s check


@pytest.mark.parametrize("sim_name", SIMS)
def test_shadow_collides_only_the_mjcf_pairs_unless_told_all(registry, sim_name):
    """The default Shadow (``self_collision: mjcf_pairs``): at random poses every touching hand-hand pair is one of
    the 18 the MJCF lists (read from MuJoCo's compiled model, not from our list); with ``self_collision: all`` (set
    through the registry) the same poses touch pairs outside it too."""
    from ges_plugins.hands.shadow.assets import compile_model
    from ges_plugins.hands.shadow.convert import contact_pairs_from_mjmodel

    listed = {frozenset(pair) for pair in contact_pairs_from_mjmodel(compile_model())}
    every = load_registry(overrides=("settings.hand.shadow.self_collision=all",)).build_hand("shadow")
    seen = {}
    for label, hand in (("mjcf_pairs", registry.build_hand("shadow")), ("all", every)):
        lim = hand.description.limits_array
        seen[label] = set()
        with registry.build_sim(sim_name, SceneConfig(self_collision=True, gravity=0.0)) as sim:
            sim.load_hand(hand, floating=False)
            for q in np.random.default_rng(3).uniform(lim[:, 0], lim[:, 1], size=(12, len(lim))):
                sim.set_hand_state(hand.description.apply_couplings(q)[None])
                sim.engine_step()
                seen[label] |= set(_hand_pairs(sim))
    assert seen["mjcf_pairs"] and seen["mjcf_pairs"] <= listed
    assert seen["all"] - listed


@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_the_sim_check_starts_the_open_hand_clear_of_the_box(registry, sim_name):
    """The wrist link's origin 5 mm above the box left the Allegro's palm box 6.7 mm inside it (the engines' deepest
    hand-box contact after the first step); the start pose is raised until the collision geometry over the box lies
    START_CLEARANCE above its top. Forward kinematics (pytorch-kinematics and the URDF's collision box, no engine)
    puts the palm's lowest point that high, and the engine then sees no hand-box contact at the start. A failed
    check whose hand still started deeper than START_OVERLAP_NOTE inside says so; a passing one does not."""
    import dataclasses

    import torch

    from ges_core.collision_points import collision_points
    from ges_core.hand_prep.engine_urdf import engine_urdf
    from ges_core.kinematics import HandKinematics
    from ges_core.sim_check import (
        START_CLEARANCE,
        START_OVERLAP_NOTE,
        _object_bounds,
        build_check_object,
        clear_of_object,
        grasp_start_pose,
    )
    from ges_core.transforms import pose_to_matrix

    hand = registry.build_hand("allegro")
    d = hand.description
    config = SimCheckConfig()
    with registry.build_sim(sim_name, config.scene) as sim:
        report = run_sim_check(hand, sim, config)
    with registry.build_sim(sim_name, config.scene) as sim:
        obj = build_check_object(config)
        sim.load_object(obj)
        bounds = _object_bounds(sim, obj)
    kin = HandKinematics.from_hand(hand)
    palm = collision_points(engine_urdf(hand.urdf_text(), hand.urdf_path().parent))[d.wrist.link]
    palm_in_base = kin.link_poses(torch.as_tensor(np.asarray(d.open_pose))[None], [d.wrist.link])[0, 0].numpy()

    def palm_above_top(base: np.ndarray) -> float:
        pose = pose_to_matrix(base) @ palm_in_base
        return float((palm @ pose[:3, :3].T + pose[:3, 3])[:, 2].min() - bounds[1, 2])

    origin_rule = grasp_start_pose(hand, bounds.mean(axis=0), config.closure, object_top=bounds[1, 2])
    assert palm_above_top(origin_rule) < -0.003  # the origin rule's start: the palm inside the box
    assert palm_above_top(clear_of_object(hand, origin_rule, bounds)) == pytest.approx(START_CLEARANCE, abs=1e-9)
    assert report.start_overlap is None and report.ok and "inside the box" not in report.format()
    deeper = dataclasses.replace(
        report, tip_forces=np.zeros_like(report.tip_forces), start_overlap=(d.wrist.link, 0.03)
    )
    assert "the open hand started 30.0 mm inside the box (base_link)" in deeper.format()
    shallow = dataclasses.replace(deeper, start_overlap=(d.wrist.link, START_OVERLAP_NOTE / 2))
    assert "inside the box" not in shallow.format() and "FAILED" in shallow.format()
