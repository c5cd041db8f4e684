"""Small shared helpers for the Stage 2 environment tests: grasp targets, a real GraspEnv, a small Stage 1 dataset.

The same scene as tests/test_env_grasp_env.py: the registry's Allegro hand palm-down over a
5 x 7 x 10 cm box resting at the origin, the pre-grasp 2 cm above the grasp.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ges_core.dataset import open_dataset
from ges_core.env.grasp_env import EnvConfig, GraspEnv, GraspTargets
from ges_core.hand import HandModel
from ges_core.objects.library import LibraryConfig
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import grasp_start_pose
from ges_core.synthesis import PregraspConfig, SynthesisConfig, pregrasp, run_synthesis
from ges_core.synthesis.types import Grasp

__all__ = ["HELD_CLOSURE", "build_grasp_env", "grasp_dataset", "grasp_targets", "held_grasp_targets"]

HELD_CLOSURE = 0.5
"""Closure of :func:`held_grasp_targets`. Measured (PyBullet, Allegro, the scripted expert with the hand's squeeze,
copies of the grasp moved up to 2 mm or with joint noise of 0.02 rad): 0.5 held 31 of 32, 0.45 and 0.55 15 and 16
of 16; SAPIEN held every copy. The 0.7 grasp of :func:`grasp_targets` puts the fingertips 2.5 cm inside the box
and presses the palm on its top (50 N): PyBullet held 15 of 32 copies, and the same grasp flipped between held
and dropped with the BLAS kernel numpy picked (OpenBLAS SkylakeX vs Haswell: last bits of a quaternion product)."""


def grasp_targets(hand: HandModel, n: int) -> GraspTargets:
    """n copies of one palm-down grasp of the test box (closure 0.7), pre-grasp 2 cm up, open fingers.

    Not a grasp to judge a lift by (the fingertips' goal lies 2.5 cm inside the box): see
    :func:`held_grasp_targets`."""
    d = hand.description
    pose = grasp_start_pose(hand, np.array([0.0, 0.0, 0.05]), 0.7, object_top=0.1)
    pre = pose.copy()
    pre[2] += 0.02  # the paper's pre-grasp: 2 cm back along the approach (palm-down: up)
    rows = [pose, d.closed_pose(0.7), pre, np.asarray(d.open_pose)]
    return GraspTargets(*(np.tile(r, (n, 1)) for r in rows))


def held_grasp_targets(hand: HandModel, shifts: np.ndarray) -> GraspTargets:
    """One palm-down grasp of the test box per row of ``shifts`` (n, 3) m, world: that env's grasp and
    pre-grasp moved by it. Closure :data:`HELD_CLOSURE`; the pre-grasp is Stage 1's
    (:func:`ges_core.synthesis.pregrasp`: 2 cm up, fingers open, the thumb kept opposed), so closing is a
    flexion of every finger and the thumb does not sweep the box sideways on its way in."""
    d = hand.description
    pose = grasp_start_pose(hand, np.array([0.0, 0.0, 0.05]), HELD_CLOSURE, object_top=0.1)
    grasp = Grasp(hand=d.name, wrist_pose=pose, q=np.asarray(d.closed_pose(HELD_CLOSURE)))
    # palm-down: the hand moves down. opening="open_pose": the opened hand HELD_CLOSURE was measured with (Stage 1's
    # default retracts each finger 3 cm from its contact; this synthetic grasp is not refined, its tips lie inside
    # the box, and retracted from there PyBullet's expert no longer lifted it)
    pre = pregrasp(hand, grasp, approach=np.array([0.0, 0.0, -1.0]), config=PregraspConfig(opening="open_pose"))
    shifts = np.asarray(shifts, dtype=np.float64)
    move = np.concatenate([shifts, np.zeros((len(shifts), 4))], axis=1)
    rows = [np.tile(r, (len(shifts), 1)) for r in (grasp.wrist_pose, grasp.q, pre.wrist_pose, pre.q)]
    return GraspTargets(rows[0] + move, rows[1], rows[2] + move, rows[3])


def build_grasp_env(
    sim_name: str, n: int, *, sim_wrapper=None, targets: Callable[[HandModel], GraspTargets] | None = None, **cfg
) -> GraspEnv:
    """A GraspEnv of ``n`` envs on the real backend ``sim_name`` (wrapped by ``sim_wrapper(sim)`` if given)
    with ``EnvConfig(**cfg)``; ``targets(hand)`` gives the grasps (default: :func:`grasp_targets`)."""
    reg = load_registry()
    hand = reg.build_hand("allegro")
    sim = reg.build_sim(sim_name, SceneConfig(num_envs=n))
    sim = sim_wrapper(sim) if sim_wrapper else sim
    box = box_asset((0.025, 0.035, 0.05), density=300.0, object_id="test/box")
    grasps = targets(hand) if targets else grasp_targets(hand, n)
    return GraspEnv(sim, hand, box, grasps, EnvConfig(**cfg))


def grasp_dataset(root: Path, candidates: Sequence[str], count: int = 2) -> tuple[str, ...]:
    """Stage 1 (Allegro, 60-step hold) into ``root`` on ``candidates`` in order until ``count`` of them have a stored
    grasp; those ids. Stage 1's verdicts change as it evolves, so the tests name candidates rather than the winners."""
    library = LibraryConfig(sources=("procedural",), procedural_count=1)
    config = SynthesisConfig.model_validate({"library": library, "validate": {"hold_steps": 60}})
    found: list[str] = []
    for oid in candidates:
        run_synthesis([oid], ["allegro"], config, root)
        found += [oid] if open_dataset(root).get(oid, "allegro").pregrasp is not None else []
        if len(found) == count:
            return tuple(found)
    raise AssertionError(f"Stage 1 stored grasps for {found} only, of {list(candidates)}")
