"""Validation with the hand's actuator limits (ValidateConfig.drive_limits, the Ability's settings.validate).

A real Ability grasp of the demo set that SAPIEN holds. Without friction anchors, PyBullet drops it with the
uncapped PD drives (the thumb is driven millimetres into the sphere; docs/hands/ability.md); with them (the
backend's default, tests/test_pybullet_friction_anchors.py) it holds it capped or not."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.physics.validate import ValidateConfig, validate_grasp
from ges_core.synthesis.types import Grasp

from conftest import ability_hand

pytestmark = [pytest.mark.sim, pytest.mark.usefixtures("unprepared_hands")]

# procedural/sphere/000, ges synth --hands ability (seed 0, 2026-12-02): base poses in the object frame
# (m, wxyz), joints in the hand's order (couplings applied by the validator).
GRASP_POSE = [-0.054780282, -0.084490240, 0.114276465, 0.446915654, -0.346400229, 0.740285631, 0.363662569]
GRASP_Q = [-2.0915699, 0.51811063, 0.7589308, 1.52633464, 0.5032196, 1.2559355, 0.30251762, 1.04375494, 0.21983695]
GRASP_Q += [0.95675164]
PRE_POSE = [-0.054780282, -0.084490240, 0.134276465, 0.446915654, -0.346400229, 0.740285631, 0.363662569]
PRE_Q = [-2.06923028, 0.0, 0.10860586, 0.8384587, 0.07188120, 0.79958517, 0.0, 0.72349796, 0.0, 0.72349796]


@pytest.fixture(scope="module")
def setup(unprepared_hands):
    registry = load_registry()
    hand = ability_hand()
    cfg = SynthesisConfig().for_hand("ability", hand.description.settings)
    obj = cfg.library.build().get("procedural/sphere/000")
    grasp = Grasp("ability", np.array(GRASP_POSE), np.array(GRASP_Q))
    pre = Grasp("ability", np.array(PRE_POSE), np.array(PRE_Q))
    return registry, hand, cfg, obj, grasp, pre


def _validate(setup, sim_name: str, config: ValidateConfig, spy: list | None = None, *, overrides: tuple = ()):
    registry, hand, cfg, obj, grasp, pre = setup
    registry = load_registry(overrides=overrides) if overrides else registry
    with registry.build_sim(sim_name, cfg.scene) as sim:
        if spy is not None:
            real = sim.set_drive_limits
            sim.set_drive_limits = lambda limits: (spy.append(limits), real(limits))[1]
        return validate_grasp(sim, hand, obj, grasp, pre, config)


def test_the_ability_validates_with_its_effort_limits(setup):
    """The hand's settings turn the caps on; the validator sets the effort limits for the trial and lifts them."""
    _, hand, cfg, *_ = setup
    assert cfg.validate_.drive_limits
    spy: list = []
    assert _validate(setup, "pybullet", cfg.validate_, spy).success
    assert np.array_equal(spy[0], hand.description.effort_limits_array) and spy[-1] is None


@pytest.mark.parametrize("iterations", [80, 100, 120])
def test_uncapped_pybullet_without_friction_anchors_drops_what_the_defaults_hold(setup, iterations):
    """Same grasp at PyBullet's default 100 solver iterations and 20 % either side: uncapped and without friction
    anchors PyBullet drops the sphere; with the anchors it holds it capped and uncapped; SAPIEN holds it both ways."""
    _, _, cfg, *_ = setup
    uncapped = cfg.validate_.model_copy(update={"drive_limits": False})
    solver = f"settings.sim.pybullet.solver_iterations={iterations}"
    bare = (solver, "settings.sim.pybullet.friction_anchors=false")
    assert _validate(setup, "pybullet", uncapped, overrides=bare).reason == "dropped"
    assert _validate(setup, "pybullet", uncapped, overrides=(solver,)).success
    assert _validate(setup, "pybullet", cfg.validate_, overrides=(solver,)).success


def test_sapien_holds_the_sphere_capped_and_uncapped(setup):
    _, _, cfg, *_ = setup
    assert _validate(setup, "sapien", cfg.validate_).success
    assert _validate(setup, "sapien", cfg.validate_.model_copy(update={"drive_limits": False})).success
