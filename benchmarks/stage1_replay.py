"""Replays a dataset's stored grasps under changed validation settings: robust counts before and after, paired.

Stage 1 changes that act only after refinement (how the hand closes, lifts or holds) need no new search to be
measured: each stored grasp is validated again in the dataset's primary simulator, its nominal trial and, when
that passes, every robust-validation trial, once with the dataset's own settings (the **replay**, which should
give the stored verdicts: the table says how many it does) and once with ``-o KEY=VALUE`` changes to the
synthesis config (the **change**). Both sides run the same code, so the comparison is paired and its difference
is the change's alone.

Records: per hand, every refined grasp whose stored verdict is not robust (validated-not-robust and
nominal-failed), plus ``--controls`` robust ones drawn with a seed (to see what the change costs where things
work). ``--all`` takes every refined grasp instead.

    python benchmarks/stage1_replay.py runs/stage1_dataset_procedural_v2 --hands allegro shadow \\
        -o validate.lift_steps=120 --controls 30 --workers 2 --results stage1_replay_slow_lift

Prints a table per hand and writes ``benchmarks/results/<--results>.json`` (default ``stage1_replay.json``).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ges_core.dataset import open_dataset, software_versions

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("-o", dest="overrides", action="append", default=[], help="KEY=VALUE of SynthesisConfig")
    parser.add_argument("--controls", type=int, default=30, help="robust records replayed besides the others")
    parser.add_argument("--all", action="store_true", help="every refined record")
    parser.add_argument("--categories", nargs="+", help="only these categories")
    parser.add_argument("--seed", type=int, default=0, help="seed of the control draw")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--results", default="stage1_replay", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the replays
    if not args.overrides:
        parser.error("give at least one -o KEY=VALUE: the change to measure")
    dataset = open_dataset(args.dataset)
    chosen = _chosen(dataset, args)
    jobs = [(str(args.dataset), r.object_id, r.hand, args.overrides) for r in chosen]
    start = time.perf_counter()
    print(f"replaying {len(jobs)} records ({', '.join(args.hands)}) with {args.overrides}, {args.workers} worker(s)")
    rows = []
    with ProcessPoolExecutor(args.workers, initializer=_one_thread) as pool:
        for i, row in enumerate(pool.map(_replay, jobs), 1):
            rows.append(row)
            print(f"[{i}/{len(jobs)}] {row['hand']} {row['object_id']}: stored {row['stored']}, "
                  f"replay {row['replay']}, change {row['change']}", flush=True)  # fmt: skip
    summary = {hand: _summary([r for r in rows if r["hand"] == hand]) for hand in args.hands}
    for hand, s in summary.items():
        print(f"\n{hand}:\n" + _format(s))
    write_results(
        results,
        {
            "dataset": str(args.dataset), "overrides": args.overrides, "controls": args.controls, "all": args.all,
            "categories": args.categories, "seed": args.seed, "seconds": round(time.perf_counter() - start, 1),
            "summary": summary, "rows": rows, "versions": software_versions("sapien", "pybullet"),
            "code": code_state(),
        },
    )  # fmt: skip


def _chosen(dataset, args) -> list:
    """The records replayed (module docs), dataset order."""
    rng = np.random.default_rng(args.seed)
    out = []
    for hand in args.hands:
        refined = [r for r in dataset.records(hand=hand) if r.grasp is not None and r.steps["refinement"].ok]
        if args.categories:
            refined = [r for r in refined if r.category in args.categories]
        robust = [r for r in refined if _verdict(r) == "robust"]
        if args.all:
            out += refined
            continue
        keep = {r.object_id for r in refined if _verdict(r) != "robust"}
        picks = rng.choice(len(robust), size=min(args.controls, len(robust)), replace=False) if robust else []
        keep |= {robust[int(i)].object_id for i in picks}
        out += [r for r in refined if r.object_id in keep]
    return out


def _verdict(record) -> str:
    """robust, validated (nominal held, a perturbation did not) or failed (nominal failed), primary simulator:
    :func:`ges_core.experts.by_grasp.grasp_group`, whose ``refined`` (refined, nominal failed) this table calls
    ``failed`` (every replayed record refined)."""
    from ges_core.experts.by_grasp import grasp_group

    group = grasp_group(record)
    return "failed" if group == "refined" else group


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)
    os.environ["OMP_NUM_THREADS"] = "1"


_CACHE: dict = {}


def _replay(job) -> dict:
    """One record validated again with its dataset's settings and with the changed ones (module docs)."""
    from ges_core.config import apply_overrides, parse_model
    from ges_core.env.grasp_source import library_for, record_asset
    from ges_core.registry import load_registry
    from ges_core.synthesis import SynthesisConfig
    from ges_core.synthesis.physics.robust import robust_validate
    from ges_core.synthesis.physics.scene import TrialScenes
    from ges_core.synthesis.physics.validate import validate_grasp
    from ges_core.synthesis.types import Grasp

    root, object_id, hand, overrides = job
    if root not in _CACHE:  # once per worker process: the dataset, its library and both configs
        dataset = open_dataset(root)
        base = SynthesisConfig.of_dataset(dataset)
        changed = parse_model(SynthesisConfig, apply_overrides(base.dump(), overrides), where="-o")
        _CACHE[root] = (dataset, library_for(dataset), load_registry(), {}, base, changed)
    dataset, library, registry, hands, base, changed = _CACHE[root]
    record = dataset.get(object_id, hand)
    if hand not in hands:
        hands[hand] = registry.build_hand(hand)
    model = hands[hand]
    asset = record_asset(library, record)
    grasp = Grasp(hand, record.grasp.wrist_pose, record.grasp.q)
    pre = Grasp(hand, record.pregrasp.wrist_pose, record.pregrasp.q)
    row = {"object_id": object_id, "hand": hand, "category": record.category, "split": record.split,
           "stored": _verdict(record)}  # fmt: skip
    for side, config in (("replay", base), ("change", changed)):
        cfg = config.for_hand(hand, model.description.settings)
        scenes = TrialScenes(registry.build_sim, record.simulator, cfg.scene, model)
        with scenes.open() as sim:
            nominal = validate_grasp(sim, model, asset, grasp, pre, cfg.validate_)
        trials = []
        if nominal.success and cfg.robust.enabled:
            robust = robust_validate(scenes, asset, grasp, pre, cfg.validate_, cfg.robust, seed=record.seed)
            trials = [(t.name, t.reason) for t in robust.trials]
        held = nominal.success and all(reason == "success" for _, reason in trials)
        row[side] = "robust" if held else "validated" if nominal.success else "failed"
        row[f"{side}_nominal"] = nominal.reason
        row[f"{side}_trials"] = trials
    return row


def _summary(rows: list[dict]) -> dict:
    """Counts per stored verdict: records, replay robust, change robust, flips up and down (replay -> change)."""
    out = {}
    for group in ("robust", "validated", "failed", "all"):
        chosen = [r for r in rows if group == "all" or r["stored"] == group]
        out[group] = {
            "records": len(chosen),
            "replay_matches_stored": sum(r["replay"] == r["stored"] for r in chosen),
            "replay_robust": sum(r["replay"] == "robust" for r in chosen),
            "change_robust": sum(r["change"] == "robust" for r in chosen),
            "replay_nominal": sum(r["replay"] != "failed" for r in chosen),
            "change_nominal": sum(r["change"] != "failed" for r in chosen),
            "up": sum(r["replay"] != "robust" and r["change"] == "robust" for r in chosen),
            "down": sum(r["replay"] == "robust" and r["change"] != "robust" for r in chosen),
        }
    return out


def _format(summary: dict) -> str:
    lines = ["| stored verdict | records | replay = stored | robust: replay -> change | up | down | nominal held |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for group, s in summary.items():
        lines.append(
            f"| {group} | {s['records']} | {s['replay_matches_stored']} | {s['replay_robust']} -> "
            f"{s['change_robust']} | {s['up']} | {s['down']} | {s['replay_nominal']} -> {s['change_nominal']} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
