"""Held-out pose trials: do a dataset's robust grasps hold pose offsets they were not chosen on?

Robust validation runs 3 seeded pose trials (``robust.seed`` 0) and the attempt loop keeps the first placement
that holds them, so a "robust" grasp may only hold those 3. This re-runs every robust grasp of a dataset (robust
in that simulator) under the pose trials of other seeds (``--seeds``, default 1 2 3: other directions and turn
signs, the same ``pose_shift`` and ``pose_turn_deg``, the hand's drive limits on), in each simulator asked, and
counts the grasps that hold all of them. Mass, friction and the limits-only trial are deterministic, so rerunning
them would only repeat their verdicts; they are left out.

Prints one row per hand x simulator and writes ``benchmarks/results/NAME.json`` (default NAME ``stage1_heldout``).

    python benchmarks/stage1_heldout.py --dataset DIR [--sims sapien pybullet] [--seeds 1 2 3] [--label TEXT]
        [--results NAME]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ges_core.dataset import open_dataset
from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.physics.robust import robust_validate
from ges_core.synthesis.physics.scene import TrialScenes
from ges_core.synthesis.types import Grasp
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results


def heldout(dataset: Path, sims: list[str], seeds: list[int]) -> list[dict]:
    """Per hand x simulator: robust grasps, those that also held every held-out pose trial, the failures."""
    ds = open_dataset(dataset)
    registry, run = load_registry(), SynthesisConfig.of_dataset(ds)
    rows = []
    for hand_name in sorted({e["hand"] for e in ds.entries}):
        hand = registry.build_hand(hand_name)
        cfg = run.for_hand(hand_name, hand.description.settings)
        library = cfg.library.build()
        trials = [cfg.robust.model_copy(update={"seed": s, "mass_scales": (), "friction_floor": None,
                                                 "limits_trial": False}) for s in seeds]  # fmt: skip
        for sim_name in sims:
            row = {"hand": hand_name, "simulator": sim_name, "robust": 0, "held_all": 0, "trials": 0,
                   "trials_failed": 0, "failures": {}}  # fmt: skip
            started = time.perf_counter()
            for record in ds.records(hand=hand_name):
                verdict = record.validations.get(sim_name)
                if verdict is None or not verdict.robust:
                    continue
                row["robust"] += 1
                obj = library.get(record.object_id)
                grasp = Grasp(hand_name, record.grasp.wrist_pose, record.grasp.q)
                pre = Grasp(hand_name, record.pregrasp.wrist_pose, record.pregrasp.q)
                failed = []
                scenes = TrialScenes(registry.build_sim, sim_name, cfg.scene, hand)
                for seed, config in zip(seeds, trials, strict=True):
                    result = robust_validate(scenes, obj, grasp, pre, cfg.validate_, config, seed=record.seed)
                    row["trials"] += len(result.trials)
                    failed += [f"seed {seed} {t.name}: {t.reason}" for t in result.trials if not t.success]
                row["trials_failed"] += len(failed)
                row["held_all"] += not failed
                if failed:
                    row["failures"][record.object_id] = failed
            row["seconds"] = round(time.perf_counter() - started, 1)
            rows.append(row)
            print(f"{hand_name:8s} {sim_name:9s} robust {row['robust']:3d}, held every held-out trial "
                  f"{row['held_all']:3d}; held-out trials failed {row['trials_failed']} of {row['trials']}",
                  flush=True)  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="a Stage 1 dataset folder (robust trials on)")
    parser.add_argument("--sims", nargs="+", default=["sapien"], help="simulators to re-run in (default: sapien)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3], help="robust.seed of the held-out trials")
    parser.add_argument("--label", default="", help="what the dataset is (command, commit), stored with the results")
    parser.add_argument("--results", default="stage1_heldout", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the trials
    set_torch_threads()
    if 0 in args.seeds:
        parser.error("seed 0 is the trials the grasps were chosen on; give other seeds")
    rows = heldout(args.dataset, args.sims, args.seeds)
    write_results(results, {"benchmark": "stage1_heldout", "dataset": str(args.dataset), "label": args.label,
                            "seeds": args.seeds, "rows": rows, "code": code_state()})  # fmt: skip


if __name__ == "__main__":
    main()
