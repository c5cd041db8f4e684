"""Every hand in every simulator, against each other and against pytorch-kinematics.

These run the real engines at small size: the same scene must give the same physics in SAPIEN
and PyBullet, and both must agree with an independent kinematics library.
"""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.lint.checks_physics import check_fk_matches_sims
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import SimCheckConfig, run_sim_check

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
    for z in heights:
        assert z == pytest.approx(half_extents[2], abs=2e-3)
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
