"""``ges eval-experts`` on a Stage 1 dataset: success per expert and split with randomization on and off, and cost.

Experts: the scripted baseline and two other settings of it (``fast``: fingers closed over 15 control steps
instead of 30; ``gentle``: each fingertip driven to press 2 N instead of the hand's squeeze force). A close of 60
steps cannot meet the paper's protocol inside the 200-step episode (approach 15 + close 60 + pause 5 + carry 45,
then 100 control steps of hold): measured 0/32 paper, 32/32 peers on the demo dataset (Allegro, SAPIEN).

Per hand x randomization on/off: the matrix (resumed from ``--out``), its Table 2-style rows under both protocols,
the wall time of this run's cells and the mean time per cell.

    python benchmarks/eval_experts.py [--results NAME]                  # runs/demo/dataset, both hands, sapien
    python benchmarks/eval_experts.py DATASET --hand shadow --episodes 4 --workers 2 [--results NAME]

Writes ``benchmarks/results/NAME.json`` (default NAME ``eval_experts``) and prints one table per run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from ges_core.env.evaluate import BaselineConfig
from ges_core.env.evaluate.fanout import Fanout
from ges_core.experts import parse_expert
from ges_core.experts.evaluate import RANDOMIZED, evaluate_experts
from ges_core.experts.table import expert_table, split_rates
from ges_core.objects.splits import SPLITS
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

ROOT = Path(__file__).resolve().parent
EXPERTS = ("scripted", "fast=scripted:close_steps=15", "gentle=scripted:squeeze_force=2.0")


def run(args: argparse.Namespace, hand: str, randomized: bool) -> dict:
    """One matrix (resumed if ``args.out`` holds it): rates per expert and split, and the cells' cost."""
    env = {"randomization": RANDOMIZED if randomized else {"enabled": False}}
    data = {"hand": hand, "sim": args.sim, "envs": args.episodes, "selection": args.select, "env": env}
    config = BaselineConfig.model_validate(data)
    start = time.perf_counter()
    report = evaluate_experts(args.dataset, config, [parse_expert(e) for e in EXPERTS], args.out, progress=True,
                              fanout=Fanout(workers=args.workers))  # fmt: skip
    wall = time.perf_counter() - start
    cells = [c for obj in json.loads(report.path.read_text())["cells"].values() for c in obj.values()]
    for protocol in ("paper", "peers"):
        print(f"\n{hand} / {args.sim} / randomization {'on' if randomized else 'off'}\n")
        print(expert_table(report.matrix, protocol))
    print(report.summary())
    return {
        "hand": hand,
        "sim": args.sim,
        "randomized": randomized,
        "episodes_per_cell": args.episodes,
        "objects": len(report.matrix.object_ids),
        "experts": list(report.matrix.experts),
        "rates": {
            p: {s or "all": split_rates(report.matrix, p, s) for s in (*SPLITS, None)} for p in ("paper", "peers")
        },  # fmt: skip
        "cells_evaluated": report.evaluated,
        "cells_reused": report.reused,
        "errors": report.errors,
        "wall_seconds_this_run": round(wall, 1),
        "mean_cell_seconds": round(statistics.mean(c["seconds"] for c in cells), 2) if cells else None,
        "matrix": str(report.path),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", type=Path, nargs="?", default=ROOT.parent / "runs" / "demo" / "dataset")
    p.add_argument("--hand", action="append", help="hand (repeatable; default allegro and shadow)")
    p.add_argument("--sim", default="sapien")
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--select", default="validated")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT.parent / "runs" / "eval_experts")
    p.add_argument("--results", default="eval_experts", help="benchmarks/results/NAME.json")
    args = p.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the evaluations
    set_torch_threads(1)
    runs = [run(args, hand, randomized) for hand in args.hand or ["allegro", "shadow"] for randomized in (True, False)]
    write_results(results, {"code": code_state(), "dataset": str(args.dataset), "runs": runs})


if __name__ == "__main__":
    main()
