"""How closely a floating hand follows its wrist targets at, near and away from the wrist's gimbal lock.

The floating wrist turns through hinges rx, ry, rz (``R = Rx Ry Rz``); at ry = +-pi/2 rx and rz turn about one axis.
A palm-down start with the fingers along world x (``ges_core.sim_check.grasp_start_pose``) sits there for the
Allegro. From each start below the wrist targets turn 15 degrees about world x, y or z over 50 control steps, then
hold for 50; the table gives the worst angle between the hand's base (``SimBackend.wrist_pose``) and its target over
the 100 steps, per engine. Starts: at the lock; 0.1 and 1 degree off it (turned about world y); tilted 1 degree
about world x; 20 degrees away from it (turned about world z). A turn about world y from the lock takes ry through
pi/2 (docs/simulators.md, "Gimbal lock").

    python benchmarks/wrist_lock.py [--hand allegro] [--sim sapien --sim pybullet] [--results wrist_lock]

Results: ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402

STARTS = {
    "at the lock": Rotation.identity(),
    "0.1 deg off": Rotation.from_euler("y", -0.1, degrees=True),
    "1 deg off": Rotation.from_euler("y", -1.0, degrees=True),
    "tilted 1 deg about x": Rotation.from_euler("x", 1.0, degrees=True),
    "20 deg away": Rotation.from_euler("z", 20.0, degrees=True),
}
TURN_DEG, TURN_STEPS, HOLD_STEPS = 15.0, 50, 50


def _wxyz(rotation: Rotation) -> np.ndarray:
    return rotation.as_quat()[[3, 0, 1, 2]]


def follow_errors(sim, hand, base: np.ndarray, start: Rotation, axis: str) -> tuple[float, float]:
    """Degrees between the base's rotation and its target: the largest while the targets turn and hold, and the last.

    sim: a backend with ``hand`` loaded floating; base: (7,) pose whose position the wrist keeps; start: the rotation
    the hand is teleported to first; axis: the world axis the targets turn about (``"x"``, ``"y"`` or ``"z"``)."""
    sim.set_hand_state(np.asarray(hand.description.open_pose)[None], np.r_[base[:3], _wxyz(start)][None])
    errors = []
    for i in range(1, TURN_STEPS + HOLD_STEPS + 1):
        goal = Rotation.from_euler(axis, TURN_DEG * min(i, TURN_STEPS) / TURN_STEPS, degrees=True) * start
        sim.set_wrist_targets(np.r_[base[:3], _wxyz(goal)][None])
        sim.step()
        got = Rotation.from_quat(sim.wrist_pose()[0, [4, 5, 6, 3]])
        errors.append(float(np.degrees((goal.inv() * got).magnitude())))
    return max(errors), errors[-1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hand", default="allegro")
    p.add_argument("--sim", action="append", help="simulator (repeatable; default sapien and pybullet)")
    p.add_argument("--results", default="wrist_lock", help="benchmarks/results/NAME.json")
    args = p.parse_args()
    results = results_path(args.results)

    from ges_core.registry import load_registry
    from ges_core.sim import SceneConfig
    from ges_core.sim_check import grasp_start_pose
    from ges_core.transforms import quat_to_euler_xyz

    registry = load_registry()
    hand = registry.build_hand(args.hand)
    base = grasp_start_pose(hand, np.array([0.0, 0.0, 0.3]), 0.7)
    ry = float(quat_to_euler_xyz(base[None, 3:])[0, 1])
    palm_down = Rotation.from_quat(base[[4, 5, 6, 3]])
    sims = args.sim or ["sapien", "pybullet"]
    rows = []
    for sim_name in sims:
        with registry.build_sim(sim_name, SceneConfig()) as sim:
            sim.load_hand(hand, floating=True)
            for label, offset in STARTS.items():
                errors = {axis: follow_errors(sim, hand, base, offset * palm_down, axis)[0] for axis in "xyz"}
                rows.append({"sim": sim_name, "start": label, **{f"turn_{a}_deg": e for a, e in errors.items()}})
    print(f"hand {args.hand}: palm-down start at ry = {ry:.6f} rad; worst base error (degrees) while the targets turn")
    print(f"{TURN_DEG:.0f} degrees in {TURN_STEPS} steps and hold {HOLD_STEPS}:\n")
    print("| sim | start | about world x | y | z |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['sim']} | {r['start']} | {r['turn_x_deg']:.2f} | {r['turn_y_deg']:.2f} | {r['turn_z_deg']:.2f} |")
    meta = {"hand": args.hand, "sims": sims, "start_ry": ry, "turn_deg": TURN_DEG, "turn_steps": TURN_STEPS,
            "hold_steps": HOLD_STEPS, "time": time.strftime("%Y-%m-%d %H:%M"), **code_state()}  # fmt: skip
    write_results(results, {"meta": meta, "rows": rows})


if __name__ == "__main__":
    main()
