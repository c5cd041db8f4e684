"""Stage 1 Table 1: per hand x simulator, step success and time per object, physics-validated success.

Runs the pipeline on the built-in demo objects (``ges_core.synthesis.run.demo.DEMO_OBJECTS``, all
convex or pre-decomposed: no CoACD run) for each hand, refining in each simulator and validating every
grasp in both simulators (cross-simulator agreement). One thread (``torch.set_num_threads(1)``, one
process). Prints markdown and writes ``benchmarks/results/NAME.json`` (default NAME ``stage1_table1``).

    python benchmarks/stage1_table1.py [--objects N] [--hands shadow allegro] [--sims sapien pybullet] [--attempts K]
        [--results NAME]

``--attempts`` (default: ``SynthesisConfig.attempts``, 3) is how many wrist placements each object may
try (``--attempts 1``: the paper's single pass, written to ``stage1_table1_attempts1.json`` unless ``--results``
names the file).

Paper (Table 1, A100): contacts 87.7 %, retargeting 88.9 %, refinement 91.5 %; 0.15 / 0.03 / 5.15 s.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import torch

from ges_core.dataset import open_dataset, software_versions
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.demo import DEMO_OBJECTS
from ges_core.synthesis.run.table import agreement_rates, format_table, table_rows

from _results import code_state, results_path, write_results

PAPER = {"contacts": 0.877, "retargeting": 0.889, "refinement": 0.915, "seconds": [0.15, 0.03, 5.15]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=len(DEMO_OBJECTS), help="first N demo objects")
    parser.add_argument("--hands", nargs="+", default=["shadow", "allegro"])
    parser.add_argument("--sims", nargs="+", default=["sapien", "pybullet"])
    parser.add_argument("--attempts", type=int, default=SynthesisConfig().attempts, help="placements per object")
    parser.add_argument(
        "--results", default=None, help="benchmarks/results/NAME.json (default stage1_table1[_attempts<K>])"
    )
    args = parser.parse_args()
    default = args.attempts == SynthesisConfig().attempts
    results = results_path(args.results or ("stage1_table1" if default else f"stage1_table1_attempts{args.attempts}"))
    torch.set_num_threads(1)
    ids = list(DEMO_OBJECTS[: args.objects])
    rows, agreement, wall = [], {}, {}
    for sim in args.sims:
        config = SynthesisConfig(
            refine_sim=sim, validate_sims=tuple(dict.fromkeys([sim, *args.sims])), attempts=args.attempts
        )
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            run_synthesis(ids, args.hands, config, Path(tmp) / "ds", progress=True)
            wall[sim] = time.perf_counter() - start
            records = list(open_dataset(Path(tmp) / "ds"))
        rows += table_rows(records)
        agreement[f"refined in {sim}"] = agreement_rates(records)
    print(format_table(rows))
    print("\ncross-simulator agreement of validation (same grasps):")
    for where, per_hand in agreement.items():
        for hand, a in per_hand.items():
            print(f"  {where}, {hand}: {a['agree']}/{a['grasps']} = {100 * a['rate']:.1f} % ({' vs '.join(a['sims'])})")
    _write(results, ids, args, rows, agreement, wall)


def _write(results: Path, ids, args, rows, agreement, wall) -> None:
    data = {
        "objects": ids,
        "hands": args.hands,
        "sims": args.sims,
        "attempts": args.attempts,
        "rows": [r.to_dict() for r in rows],
        "agreement": agreement,
        "wall_seconds_per_refine_sim": wall,
        "decomposition": "none needed: every object of the set is convex or ships convex parts (CoACD, when "
        "needed, runs once per mesh offline: ~5-20 s per mesh, cached by `ges objects prepare`)",
        "paper": PAPER,
        "machine": {"platform": platform.platform(), "threads": torch.get_num_threads()},
        "versions": software_versions(*args.sims),
        "code": code_state(),
    }
    write_results(results, data)


if __name__ == "__main__":
    main()
