"""What PyBullet's friction anchor from the first touch costs per trial, against the anchor from the load on.

``friction_anchors: on_touch`` (the PyBullet plugin's default since stop 38) checks, before every physics step until
a hand link touches the object, whether one does (``getContactPoints(object, hand)``). This replays a dataset's
stored grasps in PyBullet, the nominal validation trial of each (``validate_grasp``, a fresh backend per trial as
Stage 1 runs it), with ``true`` and with ``on_touch``, alternating, ``--repeats`` rounds, and reports per hand the
median CPU seconds of a trial (``time.process_time``, one process, one torch thread), the ratio, and in how many
trials the two settings gave the same verdict.

    python benchmarks/pybullet_anchor_cost.py DATASET [--hands allegro shadow] [--repeats 3] [--results NAME]

``DATASET``: a Stage 1 dataset with both engines' grasps, e.g. ``ges demo -o "synthesis.validate_sims=[sapien,
pybullet]"``'s ``runs/demo/dataset``. Prints a markdown table and writes
``benchmarks/results/NAME.json`` (default NAME ``pybullet_anchor_cost``).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from ges_core.dataset import open_dataset, software_versions
from ges_core.env.grasp_source import library_for, record_asset
from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.physics.validate import validate_grasp
from ges_core.synthesis.types import Grasp
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

MODES = ("true", "on_touch")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--results", default="pybullet_anchor_cost", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the trials
    set_torch_threads(1)
    dataset = open_dataset(args.dataset)
    base, library = SynthesisConfig.of_dataset(dataset), library_for(dataset)
    registries = {m: load_registry(overrides=(f"settings.sim.pybullet.friction_anchors={m}",)) for m in MODES}
    rows = []
    for hand_name in args.hands:
        hand = registries["true"].build_hand(hand_name)
        cfg = base.for_hand(hand_name, hand.description.settings)
        records = [r for r in dataset.records(hand=hand_name) if r.grasp is not None and r.pregrasp is not None]
        seconds = {m: [] for m in MODES}
        same = 0
        for record in records:
            asset = record_asset(library, record)
            grasp = Grasp(hand_name, record.grasp.wrist_pose, record.grasp.q)
            pre = Grasp(hand_name, record.pregrasp.wrist_pose, record.pregrasp.q)
            reasons = {}
            for _ in range(args.repeats):
                for mode in MODES:  # alternating: both see the same machine load
                    start = time.process_time()
                    with registries[mode].build_sim("pybullet", cfg.scene) as sim:
                        reasons[mode] = validate_grasp(sim, hand, asset, grasp, pre, cfg.validate_).reason
                    seconds[mode].append(time.process_time() - start)
            same += reasons["true"] == reasons["on_touch"]
        medians = {m: statistics.median(seconds[m]) for m in MODES}
        rows.append({"hand": hand_name, "trials": len(records), "repeats": args.repeats, "same_verdict": same,
                     "median_seconds": medians, "ratio": medians["on_touch"] / medians["true"]})  # fmt: skip
    print("| hand | grasps | CPU s per trial, median: anchor from the load / from the first touch | ratio | same |")
    print("|---|---|---|---|---|")
    for r in rows:
        m = r["median_seconds"]
        print(f"| {r['hand']} | {r['trials']} | {m['true']:.3f} / {m['on_touch']:.3f} | {r['ratio']:.3f} | "
              f"{r['same_verdict']}/{r['trials']} |")  # fmt: skip
    write_results(results, {"dataset": str(args.dataset), "rows": rows, "versions": software_versions(),
                            "code": code_state()})  # fmt: skip


if __name__ == "__main__":
    main()
