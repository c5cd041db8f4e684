"""How deep the link pairs a hand leaves out of self-collision pass into each other at a dataset's stored grasps.

A pair in the hand's ``self_collision_exclude`` (the Shadow's 170 pairs its MJCF does not list, or pairs a user left
out after ``ges hand lint``'s contact-load note) is never a contact in either engine, so two such links can pass
through each other while the hand closes. This measures whether the grasps a dataset stores rely on that: at every
record's grasp joints, PyBullet's exact closest points (GJK/EPA on the shapes the engine loads) between the two links
of every excluded pair that both have collision geometry (neighbours, which the engines never collide, are not in the
list). A negative distance is an overlap.

    python benchmarks/left_out_overlap.py DATASET [DATASET ...] [--hand shadow] [--results left_out_overlap_shadow]

Prints, per dataset, how many grasps overlap by more than 1 and 3 mm and the deepest ones with their link pairs;
writes ``benchmarks/results/NAME.json``. One process; PyBullet only (no GUI).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pybullet as p

from ges_core.dataset import open_dataset
from ges_core.registry import load_registry
from ges_plugins.sims.pybullet.scene import link_indices

from _results import code_state, results_path, write_results

SHOWN = 8
"""Deepest grasps printed per dataset."""


def left_out_pairs(hand, body: int, client: int) -> list[tuple[str, str, int, int]]:
    """(link a, link b, PyBullet index a, index b) of every excluded pair whose links the loaded body has."""
    index = link_indices(body, client)
    pairs = [tuple(pair) for pair in hand.description.self_collision_exclude]
    return [(a, b, index[a], index[b]) for a, b in pairs if a in index and b in index]


def deepest_overlap(body: int, pairs, client: int) -> tuple[float, tuple[str, str] | None]:
    """The most negative closest-point distance (m) over ``pairs`` of the body's links, and its pair (0, None: no
    pair overlaps). PyBullet measures two links of one body whatever its collision filter says."""
    worst, which = 0.0, None
    for a, b, ia, ib in pairs:
        for c in p.getClosestPoints(body, body, 0.0, ia, ib, physicsClientId=client):
            if c[8] < worst:
                worst, which = c[8], (a, b)
    return worst, which


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", help="dataset folders (their records of --hand are measured)")
    parser.add_argument("--hand", default="shadow", help="registry hand (default: shadow)")
    parser.add_argument("--results", default=None, help="NAME: write benchmarks/results/NAME.json")
    args = parser.parse_args()
    start = time.perf_counter()
    hand = load_registry().build_hand(args.hand)
    d = hand.description
    client = p.connect(p.DIRECT)
    body = p.loadURDF(str(hand.urdf_path()), useFixedBase=True, physicsClientId=client)
    joints = {p.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
              for j in range(p.getNumJoints(body, physicsClientId=client))}  # fmt: skip
    pairs = left_out_pairs(hand, body, client)
    print(f"{args.hand}: {len(pairs)} excluded link pairs with collision geometry")
    out = {"benchmark": "left_out_overlap", "hand": args.hand, "pairs": len(pairs), "datasets": {}}
    for path in args.datasets:
        rows = []
        for r in open_dataset(path).records(hand=args.hand):
            if r.grasp is None:
                continue
            q = d.apply_couplings(np.asarray(r.grasp.q, dtype=np.float64))
            for name, value in zip(r.joint_names, q, strict=True):
                p.resetJointState(body, joints[name], float(value), physicsClientId=client)
            depth, pair = deepest_overlap(body, pairs, client)
            rows.append({"object_id": r.object_id, "overlap_mm": round(-depth * 1000, 2), "pair": pair})
        rows.sort(key=lambda row: -row["overlap_mm"])
        over = {mm: sum(row["overlap_mm"] > mm for row in rows) for mm in (1, 3)}
        print(f"{path}: {len(rows)} grasps; overlapping by more than 1 mm: {over[1]}, more than 3 mm: {over[3]}")
        for row in rows[:SHOWN]:
            if row["overlap_mm"] > 0:
                print(f"   {row['overlap_mm']:.1f} mm  {row['object_id']}  {row['pair']}")
        out["datasets"][str(path)] = {"grasps": len(rows), "over_1mm": over[1], "over_3mm": over[3],
                                      "deepest": rows[:SHOWN]}  # fmt: skip
    p.disconnect(physicsClientId=client)
    out["wall_seconds"] = round(time.perf_counter() - start, 1)
    out["code"] = code_state()
    if args.results:
        write_results(results_path(args.results), out)


if __name__ == "__main__":
    main()
