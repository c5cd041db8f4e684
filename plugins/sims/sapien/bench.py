"""Interface overhead of the SAPIEN backend: raw physics step vs a full control step.

A full step is what a controller does each tick: joint and wrist targets, ``step()``, then
``joint_state``, ``link_poses`` and ``contact_forces`` of the five slot fingertips and
``object_pose``. The scene is a hand closed top-down on a box resting on the table, so the
contact path has real pairs to sum. Run ``python -m ges_plugins.sims.sapien.bench [HAND]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset, PrimitiveShape
from ges_core.sim import SceneConfig, SimBackend

__all__ = ["measure_overhead"]

_BLOCK = 50
"""Steps per timed block."""


def measure_overhead(
    hand: HandModel,
    obj: ObjectAsset,
    wrist: np.ndarray,
    grasp_q: np.ndarray,
    *,
    steps: int = 300,
    contact_offset: float | None = None,
    **scene: object,
) -> dict[str, float]:
    """µs per step of the raw physics step and of the full control step.

    Blocks of 50 raw and 50 full steps alternate until ``steps`` of each ran; each figure is the best
    block of thread CPU time (PhysX runs in the calling thread with ``cpu_workers=0``), which a
    shared, busy machine disturbs far less than wall time.
    wrist: (7,) base pose above the object; grasp_q: (K,) closed joint targets; contact_offset: per shape, metres
    (None: SAPIEN's 0.01; the framework runs the registry's setting, which :func:`main` passes).
    """
    from ges_plugins.sims.sapien.backend import SapienBackend

    with SapienBackend(SceneConfig(num_envs=1, **scene), contact_offset=contact_offset) as sim:
        sim.load_hand(hand)
        sim.load_object(obj)
        sim.set_hand_state(np.asarray(hand.description.open_pose)[None], wrist[None])
        sim.set_wrist_targets(wrist[None])
        sim.set_joint_targets(grasp_q[None])
        sim.step(120)
        raw, full = np.inf, np.inf
        for _ in range(max(1, steps // _BLOCK)):
            raw = min(raw, _time_raw(sim, _BLOCK))
            full = min(full, _time_full(sim, hand, wrist, grasp_q, _BLOCK))
        pairs = len(sim._envs[0].scene.get_contacts())
    return {"raw_step_us": raw, "full_step_us": full, "ratio": full / raw, "contact_pairs": pairs}


def _time_raw(sim: SimBackend, steps: int) -> float:
    start = time.thread_time()
    for _ in range(steps):
        sim.engine_step()
    return (time.thread_time() - start) / steps * 1e6


def _time_full(sim: SimBackend, hand: HandModel, wrist: np.ndarray, grasp_q: np.ndarray, steps: int) -> float:
    tips = hand.description.slot_tip_links
    q, w = grasp_q[None], wrist[None]
    start = time.thread_time()
    for _ in range(steps):
        sim.set_joint_targets(q)
        sim.set_wrist_targets(w)
        sim.step()
        sim.joint_state()
        sim.link_poses(tips)
        sim.contact_forces(tips, "object")
        sim.object_pose()
    return (time.thread_time() - start) / steps * 1e6


def allegro_top_down(hand: HandModel, half: float = 0.035) -> tuple[ObjectAsset, np.ndarray, np.ndarray]:
    """A box of half extent ``half`` and an Allegro palm-down wrist pose and closing targets over it."""
    from pathlib import Path

    obj = ObjectAsset(
        object_id="bench/box",
        category="box",
        mesh_path=Path("box.obj"),
        collision=(PrimitiveShape(kind="box", size=(half, half, half)),),
    )
    s = np.sqrt(0.5)  # rotation of +90 deg about y: palm normal (+x) down, fingers (+z) along +x
    wrist = np.array([-0.05, 0.0, 2 * half + 0.0167, s, 0.0, s, 0.0])
    d = hand.description
    q = np.array(d.open_pose, dtype=np.float64)
    for name, value in _ALLEGRO_CLOSE.items():
        q[d.joint_names.index(name)] = value
    return obj, wrist, q


_ALLEGRO_CLOSE = {f"joint_{j}.0": 1.0 for j in (1, 2, 3, 5, 6, 7, 9, 10, 11)} | {
    "joint_12.0": 1.3,
    "joint_13.0": 0.6,
    "joint_14.0": 0.6,
    "joint_15.0": 0.8,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("hand", nargs="?", default="allegro")
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()
    from ges_core.registry import load_registry

    registry = load_registry()
    hand = registry.build_hand(args.hand)
    if not set(_ALLEGRO_CLOSE) <= set(hand.description.joint_names):
        parser.error(f"the bench scene is posed for the Allegro hand (joint_0.0 ... joint_15.0); got '{args.hand}'")
    obj, wrist, q = allegro_top_down(hand)
    offset = registry.settings("sim", "sapien").get("contact_offset")  # what every framework run uses
    for self_collision in (False, True):
        result = measure_overhead(hand, obj, wrist, q, steps=args.steps, contact_offset=offset,
                                  self_collision=self_collision)  # fmt: skip
        print(f"contact_offset={offset} self_collision={self_collision}: "
              + ", ".join(f"{k}={v:.1f}" for k, v in result.items()))  # fmt: skip


if __name__ == "__main__":
    main()
