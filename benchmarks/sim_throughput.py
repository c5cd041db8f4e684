"""Simulator throughput: raw engine steps vs steps through ``SimBackend``, and batched FK.

For each hand x simulator the hand first closes on a box (the ``ges sim check`` scene), so
contacts exist. Then, in one run, side by side:

* raw: the engine's own step (``SimBackend.engine_step``), PD targets set once;
* interface: every step sets joint targets, steps, and reads joint state, fingertip link poses,
  fingertip contact forces and the object pose, all through ``SimBackend``;
* ratio = interface time per step / raw time per step (goal: <= 1.5);
* batched forward kinematics of every fingertip through ``ges_core.kinematics`` at batch 1024.

Timings are medians over repeats. Prints a table, writes benchmarks/results/NAME.json (default NAME sim_throughput).
Usage: python benchmarks/sim_throughput.py [--steps 500] [--repeats 5] [--hand H] [--sim S] [--results NAME]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np
import torch

from ges_core.kinematics import HandKinematics
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import SimCheckConfig, run_sim_check

from _results import results_path, write_results


def time_raw(sim, steps: int) -> float:
    """Seconds per raw engine step."""
    start = time.perf_counter()
    for _ in range(steps):
        sim.engine_step()
    return (time.perf_counter() - start) / steps


def time_interface(sim, hand, steps: int, closure: float) -> float:
    """Seconds per step with targets, step and the reads a controller makes.

    The targets equal the ones the grasp scene left set, so both loops simulate the same physics.
    """
    d = hand.description
    tips = list(d.tip_links)
    q_target = np.tile(d.closed_pose(closure), (sim.num_envs, 1))
    start = time.perf_counter()
    for _ in range(steps):
        sim.set_joint_targets(q_target)
        sim.step()
        sim.joint_state()
        sim.link_poses(tips)
        sim.contact_forces(tips, "object")
        sim.object_pose()
    return (time.perf_counter() - start) / steps


def time_fk(hand, batch: int, repeats: int) -> float:
    """Seconds per batched fingertip FK call of ``batch`` configurations."""
    d = hand.description
    kin = HandKinematics.from_hand(hand)
    lim = torch.as_tensor(d.limits_array)
    q = lim[:, 0] + torch.rand(batch, d.num_joints, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * (
        lim[:, 1] - lim[:, 0]
    )
    offsets = [f.tip_offset for f in d.fingers]
    kin.points(q, list(d.tip_links), offsets)  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        kin.points(q, list(d.tip_links), offsets)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench_pair(registry, hand_name: str, sim_name: str, steps: int, repeats: int) -> dict:
    """One row of the table."""
    hand = registry.build_hand(hand_name)
    config = SimCheckConfig(lift_steps=0, scene=SceneConfig())
    with registry.build_sim(sim_name, config.scene) as sim:
        report = run_sim_check(hand, sim, config)
        raw, iface = [], []
        for _ in range(repeats):  # interleave so drift in machine load hits both alike
            raw.append(time_raw(sim, steps))
            iface.append(time_interface(sim, hand, steps, config.closure))
    raw_s, iface_s = statistics.median(raw), statistics.median(iface)
    return {
        "hand": hand_name,
        "sim": sim_name,
        "raw_steps_per_s": 1 / raw_s,
        "interface_steps_per_s": 1 / iface_s,
        "ratio": iface_s / raw_s,
        "raw_us_per_step": raw_s * 1e6,
        "interface_us_per_step": iface_s * 1e6,
        "fingertips_touching": report.touching,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--fk-batch", type=int, default=1024)
    parser.add_argument("--hand", action="append")
    parser.add_argument("--sim", action="append")
    parser.add_argument("--results", default="sim_throughput", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the rows
    torch.set_num_threads(1)
    registry = load_registry()
    hands = args.hand or ["shadow", "allegro"]
    sims = args.sim or ["sapien", "pybullet"]
    rows = [bench_pair(registry, h, s, args.steps, args.repeats) for h in hands for s in sims]
    fk = {h: args.fk_batch / time_fk(registry.build_hand(h), args.fk_batch, args.repeats) for h in hands}
    for row in rows:
        row["fk_configs_per_s"] = fk[row["hand"]]
    print_table(rows, args.fk_batch)
    meta = {
        "steps": args.steps,
        "repeats": args.repeats,
        "fk_batch": args.fk_batch,
        "torch_threads": 1,
        "machine": platform.platform(),
        "processor": platform.processor(),
        "time": time.strftime("%Y-%m-%d %H:%M"),
    }
    write_results(results, {"meta": meta, "rows": rows})


def print_table(rows: list[dict], fk_batch: int) -> None:
    """Markdown table of the rows."""
    print(f"| hand | sim | raw steps/s | interface steps/s | ratio (goal <= 1.5) | FK configs/s (batch {fk_batch}) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['hand']} | {r['sim']} | {r['raw_steps_per_s']:.0f} | {r['interface_steps_per_s']:.0f} | "
            f"{r['ratio']:.2f} | {r['fk_configs_per_s']:.0f} |"
        )


if __name__ == "__main__":
    main()
