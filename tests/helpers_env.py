"""Small shared helpers for the Stage 2 environment tests: grasp targets and a real GraspEnv.

The same scene as tests/test_env_grasp_env.py: the registry's Allegro hand palm-down over a
5 x 7 x 10 cm box resting at the origin, the pre-grasp 2 cm above the grasp.
"""

from __future__ import annotations

import numpy as np

from ges_core.env.grasp_env import EnvConfig, GraspEnv, GraspTargets
from ges_core.hand import HandModel
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import grasp_start_pose

__all__ = ["build_grasp_env", "grasp_targets"]


def grasp_targets(hand: HandModel, n: int) -> GraspTargets:
    """n copies of one palm-down grasp of the test box (closure 0.7), pre-grasp 2 cm up, open fingers."""
    d = hand.description
    pose = grasp_start_pose(hand, np.array([0.0, 0.0, 0.05]), 0.7, object_top=0.1)
    pre = pose.copy()
    pre[2] += 0.02  # the paper's pre-grasp: 2 cm back along the approach (palm-down: up)
    rows = [pose, d.closed_pose(0.7), pre, np.asarray(d.open_pose)]
    return GraspTargets(*(np.tile(r, (n, 1)) for r in rows))


def build_grasp_env(sim_name: str, n: int, *, sim_wrapper=None, **cfg) -> GraspEnv:
    """A GraspEnv of ``n`` envs on the real backend ``sim_name`` (wrapped by ``sim_wrapper(sim)`` if given)
    with ``EnvConfig(**cfg)``."""
    reg = load_registry()
    hand = reg.build_hand("allegro")
    sim = reg.build_sim(sim_name, SceneConfig(num_envs=n))
    sim = sim_wrapper(sim) if sim_wrapper else sim
    box = box_asset((0.025, 0.035, 0.05), density=300.0, object_id="test/box")
    return GraspEnv(sim, hand, box, grasp_targets(hand, n), EnvConfig(**cfg))
