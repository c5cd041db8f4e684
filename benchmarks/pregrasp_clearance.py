"""How high above the table the stored pre-grasps hold the hand: the lowest collision point of each record's hand.

For every record of the given Stage 1 datasets that stored a pre-grasp, the lowest point of the hand's collision
geometry (``ges_core.synthesis.physics.table_clearance.finger_points``, the points the wrist search, refinement's
start and the pre-grasp keep off the table) in the object's resting frame (table top at z = 0): the pre-grasp's
joints at the pre-grasp's own pose and at the grasp pose (where validation's approach ends), and the grasp's joints
at the grasp pose. A pre-grasp below the table is one Stage 2's reaching cannot reach without meeting it. Counts per
dataset and hand:

    python benchmarks/pregrasp_clearance.py runs/demo/dataset runs/real [--results NAME]

Prints one table and writes ``benchmarks/results/pregrasp_clearance.json`` (``--results`` another name). Datasets
written before 7 December 2026 retracted every finger in full (``pregrasp.clearance`` absent): their pre-grasps
dip below the table on low contacts (docs/synthesis/refine_validate.md, "The retracted hand kept above the table").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ges_core.dataset import open_dataset
from ges_core.errors import UnknownNameError
from ges_core.kinematics import shared_kinematics
from ges_core.registry import load_registry
from ges_core.synthesis.physics.table_clearance import finger_points
from ges_core.threads import set_torch_threads
from ges_core.transforms import pose_to_matrix

from _results import code_state, results_path, write_results

CLEARANCE = 0.005
"""m: the clearance the capped retraction keeps (``pregrasp.clearance``'s default); counted as 'below 5 mm'."""


def lowest_points(folder: Path, registry) -> dict[str, np.ndarray]:
    """``{hand: (R, 3)}`` lowest hand point per record with a pre-grasp, m: pre-grasp joints at the pre-grasp pose,
    at the grasp pose, grasp joints at the grasp pose."""
    out: dict[str, list] = {}
    hands = {}
    for record in open_dataset(folder).records():
        if record.pregrasp is None:
            continue
        if record.hand not in hands:
            hands[record.hand] = registry.build_hand(record.hand)
        hand = hands[record.hand]
        points, kin = finger_points(hand), shared_kinematics(hand)
        rows = (
            (record.pregrasp.q, record.pregrasp.wrist_pose),
            (record.pregrasp.q, record.grasp.wrist_pose),
            (record.grasp.q, record.grasp.wrist_pose),
        )
        low = [points.heights(kin, np.asarray(q)[None], pose_to_matrix(np.asarray(p)))[0].min() for q, p in rows]
        out.setdefault(record.hand, []).append(low)
    return {hand: np.array(rows) for hand, rows in out.items()}


def summary(low: np.ndarray) -> dict:
    """Counts and heights (mm) of one hand's (R, 3) lowest points."""
    return {
        "records": len(low),
        "pregrasp_below_table_at_grasp_pose": int((low[:, 1] < 0).sum()),
        "pregrasp_below_table_at_its_pose": int((low[:, 0] < 0).sum()),
        "pregrasp_below_clearance_at_grasp_pose": int((low[:, 1] < CLEARANCE).sum()),
        "grasp_below_table": int((low[:, 2] < 0).sum()),
        "median_mm_at_grasp_pose": float(np.median(low[:, 1]) * 1000),
        "min_mm_at_grasp_pose": float(low[:, 1].min() * 1000),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path, help="Stage 1 dataset folders")
    parser.add_argument("--results", default="pregrasp_clearance", help="name of the JSON under benchmarks/results/")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, before any work
    set_torch_threads(1)
    registry = load_registry()
    out = {"clearance_m": CLEARANCE, "datasets": {}, "code": code_state()}
    print("| dataset | hand | records | pre-grasp below the table: at the grasp pose | at its own pose | below 5 mm "
          "at the grasp pose | grasp below the table | lowest at the grasp pose, median / min (mm) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for folder in args.datasets:
        try:
            lows = lowest_points(folder, registry)
        except UnknownNameError as error:  # a hand from a package not installed here
            raise SystemExit(f"{folder}: {error}") from None
        out["datasets"][str(folder)] = {hand: summary(low) for hand, low in lows.items()}
        for hand, s in out["datasets"][str(folder)].items():
            heights = f"{s['median_mm_at_grasp_pose']:.1f} / {s['min_mm_at_grasp_pose']:.1f}"
            counts = (
                s["pregrasp_below_table_at_grasp_pose"],
                s["pregrasp_below_table_at_its_pose"],
                s["pregrasp_below_clearance_at_grasp_pose"],
                s["grasp_below_table"],
            )
            print(f"| {folder} | {hand} | {s['records']} | " + " | ".join(map(str, counts)) + f" | {heights} |")
    write_results(results, out)


if __name__ == "__main__":
    main()
