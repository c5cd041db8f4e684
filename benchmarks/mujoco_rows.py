"""The MuJoCo rows beside SAPIEN and PyBullet: Table 1's validated column and the scripted baseline's success.

MuJoCo comes from the outside plugin package ``examples/ges-mujoco-sim`` (``pip install -e
examples/ges-mujoco-sim``); the script stops with that advice when the ``mujoco`` simulator is not registered.
Both halves run the code paths of the existing benchmarks, one process, one thread:

1. **Table 1, validated column** (``benchmarks/stage1_table1.py``'s path): ``run_synthesis`` on the 20 demo
   objects for each hand, refining and validating in each simulator (``refine_sim=S, validate_sims=(S,)``: the
   record's verdict is that simulator's), then ``table_rows``. Robust trials are off (``--robust`` turns them on):
   they do not enter the validated column.
2. **Scripted baseline** (``benchmarks/scripted_baseline.py``'s path): the same objects per split
   (``pick_objects``), its Stage 1 dataset (refined and validated in SAPIEN, reused if it exists), then
   ``evaluate_baseline`` with the scripted expert in each simulator, ``--envs`` episodes per object, records
   chosen by each ``--select`` rule.

Prints both tables and writes ``benchmarks/results/NAME.json`` (``--results NAME``, default ``mujoco_rows``).

    python benchmarks/mujoco_rows.py [--objects 20] [--hands shadow allegro] [--sims sapien pybullet mujoco]
        [--per-split 8] [--select refined validated] [--envs 1] [--skip-table1] [--skip-baseline] [--results NAME]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch
from scripted_baseline import DEFAULT_RUN, _evaluate, pick_objects, stage1_counts

from ges_core.dataset import open_dataset, software_versions
from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.demo import DEMO_OBJECTS
from ges_core.synthesis.run.table import table_rows

from _results import code_state, results_path, write_results


def table1(ids: list[str], hands: list[str], sims: list[str], robust: bool) -> tuple[list[dict], dict]:
    """Per simulator: Stage 1 refined and validated in it; the rows of ``table_rows`` and the wall time."""
    rows, wall = [], {}
    for sim in sims:
        config = SynthesisConfig(refine_sim=sim, validate_sims=(sim,))
        config = config.model_copy(update={"robust": config.robust.model_copy(update={"enabled": robust})})
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            run_synthesis(ids, hands, config, Path(tmp) / "ds", progress=True)
            wall[sim] = time.perf_counter() - start
            rows += [r.to_dict() for r in table_rows(open_dataset(Path(tmp) / "ds"))]
    return rows, wall


def format_table1(rows: list[dict], hands: list[str], sims: list[str]) -> str:
    """Markdown: one line per hand, validated / objects per simulator."""
    cell = {(r["hand"], r["simulator"]): f"{r['validated']}/{r['objects']} ({100 * r['validated_rate']:.0f} %)"
            for r in rows}  # fmt: skip
    lines = ["| hand | " + " | ".join(f"validated, {s}" for s in sims) + " |", "|---|" + "---|" * len(sims)]
    lines += [f"| {h} | " + " | ".join(cell.get((h, s), "-") for s in sims) + " |" for h in hands]
    return "\n".join(lines)


def format_baseline(runs: list[dict], sims: list[str]) -> str:
    """Markdown: per selection rule and hand, success / episodes (paper protocol) of every split per simulator."""
    by = {(r["selection"], r["hand"], r["sim"]): {row["split"]: row for row in r["rows"]} for r in runs}
    splits = list(next(iter(by.values())).keys()) if by else []
    lines = ["| selection | hand | split | " + " | ".join(sims) + " |", "|---|---|---|" + "---|" * len(sims)]
    for selection, hand in dict.fromkeys((r["selection"], r["hand"]) for r in runs):
        for split in splits:
            cells = []
            for sim in sims:
                row = by.get((selection, hand, sim), {}).get(split)
                cells.append(f"{row['paper_success']}/{row['episodes']}" if row else "-")
            lines.append(f"| {selection} | {hand} | {split} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=len(DEMO_OBJECTS), help="first N demo objects (Table 1)")
    parser.add_argument("--hands", nargs="+", default=["shadow", "allegro"])
    parser.add_argument("--sims", nargs="+", default=["sapien", "pybullet", "mujoco"])
    parser.add_argument("--robust", action="store_true", help="also run the robust trials in Table 1's run")
    parser.add_argument("--per-split", type=int, default=8, help="objects per split (scripted baseline)")
    parser.add_argument("--select", nargs="+", default=["refined", "validated"])
    parser.add_argument("--envs", type=int, default=1)
    parser.add_argument("--dataset", type=Path, default=DEFAULT_RUN / "dataset")
    parser.add_argument("--out", type=Path, default=DEFAULT_RUN / "results", help="per-object results (resumable)")
    parser.add_argument("--skip-table1", action="store_true")
    parser.add_argument("--skip-baseline", action="store_true")
    parser.add_argument("--results", default="mujoco_rows", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    if "mujoco" in args.sims and "mujoco" not in load_registry().names("sim"):
        sys.exit("the 'mujoco' simulator is not registered: pip install -e examples/ges-mujoco-sim")
    torch.set_num_threads(1)
    start = time.perf_counter()
    data: dict = {"hands": args.hands, "sims": args.sims}
    if not args.skip_table1:
        ids = list(DEMO_OBJECTS[: args.objects])
        rows, wall = table1(ids, args.hands, args.sims, args.robust)
        print("\nTable 1, validated column (refined and validated in each simulator):\n")
        print(format_table1(rows, args.hands, args.sims))
        data["table1"] = {"objects": ids, "robust": args.robust, "rows": rows, "wall_seconds_per_sim": wall}
    if not args.skip_baseline:
        data["baseline"] = baseline(args)
        print("\nScripted baseline, success / episodes (paper protocol), Stage 1 grasps from SAPIEN:\n")
        print(format_baseline(data["baseline"]["runs"], args.sims))
    data["meta"] = {
        "time": time.strftime("%Y-%m-%d %H:%M"), "wall_seconds": time.perf_counter() - start, "torch_threads": 1,
        "loadavg_end": os.getloadavg(), "cpus": os.cpu_count(), "machine": platform.platform(),
        "versions": software_versions(*args.sims), "code": code_state(), "command": " ".join(sys.argv),
    }  # fmt: skip
    write_results(results, data)


def baseline(args: argparse.Namespace) -> dict:
    """The scripted expert in every simulator on ``scripted_baseline.py``'s objects and Stage 1 dataset."""
    config = SynthesisConfig()
    objects = pick_objects(config.library.build(), args.per_split)
    ids = [oid for split in objects.values() for oid in split]
    t0 = time.perf_counter()
    run_synthesis(ids, args.hands, config, args.dataset, progress=True)  # resumes: reuses existing records
    stage1_s = time.perf_counter() - t0
    runs = [_evaluate(args, h, s, rule) for rule in args.select for h in args.hands for s in args.sims]
    for run in runs:
        print("\n" + run.pop("table"))
    return {
        "objects": objects,
        "stage1": {
            "counts": stage1_counts(args.dataset, args.hands, set(ids)),
            "seconds": stage1_s,
            "config": "SynthesisConfig() defaults: refine and validate in sapien",
        },  # fmt: skip
        "envs_per_object": args.envs,
        "runs": runs,
    }


if __name__ == "__main__":
    main()
