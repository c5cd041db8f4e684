"""Interface overhead of the PyBullet backend: raw physics step vs one full control step.

``python -m ges_plugins.sims.pybullet.bench [HAND] [--envs N] [--steps N] [--no-self-collision]
[--solver-iterations N]`` builds
the registry's hand (default ``allegro``; the scene's pose is made for it) and prints microseconds
per physics step per scene for:

* ``raw``: ``pybullet.stepSimulation`` alone (motors keep their last command);
* ``step``: :meth:`PybulletBackend.step` (drive update, object weight, state check);
* ``full``: ``set_joint_targets`` + ``step`` + ``joint_state`` + ``link_poses`` (5 tips) +
  ``contact_forces`` (5 tips) + ``object_pose``;
* ``physics``: the part of ``full`` spent inside ``stepSimulation``.

The scene: Allegro floating, palm down, fingers pressed on a 3 x 8 x 6 cm box on the table, so
the contact list is not empty.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset, PrimitiveShape
from ges_core.sim import SceneConfig
from ges_core.transforms import matrix_to_pose

from .backend import PybulletBackend
from .engine import p

__all__ = ["GRASP_BASE_POSE", "grasp_scene", "main", "measure"]

GRASP_BASE_POSE = matrix_to_pose(
    np.array([[0.0, 0.0, 1.0, -0.01], [0.0, 1.0, 0.0, -0.02], [-1.0, 0.0, 0.0, 0.115], [0.0, 0.0, 0.0, 1.0]])
)
"""Allegro base pose (palm +x down, fingers +z along world x) over :func:`_box` at the origin."""


def _box() -> ObjectAsset:
    from pathlib import Path

    shape = PrimitiveShape(kind="box", size=(0.015, 0.04, 0.03))
    return ObjectAsset(object_id="bench/box", category="box", mesh_path=Path("-"), collision=(shape,), density=300.0)


def grasp_scene(sim: PybulletBackend, hand: HandModel, closure: float = 0.55, steps: int = 60) -> np.ndarray:
    """Put the hand over the box and close it to ``closure`` in ``steps``; returns the final targets (E, K)."""
    d, n = hand.description, sim.num_envs
    sim.load_hand(hand, floating=True)
    sim.set_hand_state(np.tile(d.open_pose, (n, 1)), np.tile(GRASP_BASE_POSE, (n, 1)))
    sim.load_object(_box())
    open_q, closed_q = np.asarray(d.open_pose), d.closed_pose(closure)
    for i in range(1, steps + 1):
        sim.set_joint_targets(np.tile(open_q + (closed_q - open_q) * i / steps, (n, 1)))
        sim.step()
    return np.tile(closed_q, (n, 1))


def measure(sim: PybulletBackend, hand: HandModel, steps: int, repeats: int = 10) -> dict[str, float]:
    """Microseconds per physics step per scene (see the module docs), plus ``physics``: the time
    spent inside ``stepSimulation`` during the ``full`` loop (the fair baseline: same contacts, same
    motor load; a bare ``raw`` loop lets the drives go stale and the grasp relax).

    The loops run interleaved in ``repeats`` blocks of ``steps // repeats`` steps, each block from
    the same saved grasp state, and each keeps its fastest block: on a shared machine the
    minimum is the least disturbed estimate.
    """
    targets = grasp_scene(sim, hand)
    tips = list(hand.description.slot_tip_links)
    cids = [s.cid for s in sim._scenes]

    def raw() -> None:
        for cid in cids:
            p.stepSimulation(physicsClientId=cid)

    def full() -> None:
        sim.set_joint_targets(targets)
        sim.step()
        sim.joint_state()
        sim.link_poses(tips)
        sim.contact_forces(tips, "object")
        sim.object_pose()

    saved = [p.saveState(physicsClientId=cid) for cid in cids]
    best = dict.fromkeys(["raw", "step", "full", "physics"], np.inf)
    for _ in range(repeats):
        for name, body in (("raw", raw), ("step", sim.step), ("full", full)):
            for cid, state in zip(cids, saved, strict=True):  # every block starts from the same grasp
                p.restoreState(state, physicsClientId=cid)
            sim._state = None
            elapsed, physics = _timed_block(body, max(1, steps // repeats), name == "full")
            if name == "full" and elapsed < best["full"]:
                best["physics"] = physics
            best[name] = min(best[name], elapsed)
    return {k: v / sim.num_envs * 1e6 for k, v in best.items()}


def _timed_block(body, count: int, split: bool) -> tuple[float, float]:
    """Seconds per call of ``body`` over ``count`` calls and, with ``split``, of that the seconds inside
    ``stepSimulation`` (else 0)."""
    step_simulation, physics = p.stepSimulation, [0.0]

    def timed_step(**kwargs: int) -> None:
        start = time.perf_counter()
        step_simulation(**kwargs)
        physics[0] += time.perf_counter() - start

    p.stepSimulation = timed_step if split else step_simulation  # the backend looks it up on the module
    try:
        start = time.perf_counter()
        for _ in range(count):
            body()
        elapsed = time.perf_counter() - start
    finally:
        p.stepSimulation = step_simulation
    return elapsed / count, physics[0] / count


def main(argv: list[str] | None = None) -> None:
    """Print the timings and the full/raw and full/physics ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("hand", nargs="?", default="allegro")
    parser.add_argument("--envs", type=int, default=1)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--no-self-collision", action="store_true")
    parser.add_argument("--solver-iterations", type=int, help="the backend's solver_iterations setting")
    args = parser.parse_args(argv)
    from ges_core.registry import load_registry

    hand = load_registry().build_hand(args.hand)
    config = SceneConfig(num_envs=args.envs, self_collision=not args.no_self_collision)
    with PybulletBackend(config, solver_iterations=args.solver_iterations) as sim:
        result = measure(sim, hand, args.steps, args.repeats)
    ratios = f"full/raw {result['full'] / result['raw']:.2f}, full/physics {result['full'] / result['physics']:.2f}"
    print(" ".join(f"{k} {v:.0f} us" for k, v in result.items()), ratios)


if __name__ == "__main__":
    main()
