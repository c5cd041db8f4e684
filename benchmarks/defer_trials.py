"""Deferred perturbation trials (``robust.defer_trials``) against running every trial: same records, less time.

With deferral a placement's perturbation trials stop at its first failed one (and the other validating engines'
trials are not run), and what was left runs only when no placement of the pair holds everywhere
(docs/synthesis/refine_validate.md, "Deferred trials"). This runs Stage 1 twice on the same objects, once each
way, in one process with one torch thread, and prints per set and hand:

* whether the records are the same: kept placement, every attempt's verdicts, the kept placement's verdicts and
  trials in every engine, grasp joints and wrist pose (only the left-behind placements' stored robustness and the
  seconds may differ);
* the backends built (one per rest check, refinement, nominal trial and perturbation trial) and the CPU seconds
  of the whole run, each way, and their ratio.

The two sets are run as the docs run them: the procedural shapes (object 000 of each category) validated in
SAPIEN, the real scans in SAPIEN and PyBullet. The order of the two ways alternates between sets.

    python benchmarks/defer_trials.py [--procedural N] [--real N] [--hands allegro shadow] [--results NAME]

Writes ``benchmarks/results/NAME.json`` (default NAME ``defer_trials``).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from ges_core.dataset import open_dataset, software_versions
from ges_core.objects.library import LibraryConfig
from ges_core.objects.procedural import CATEGORIES
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.physics.scene import TrialScenes
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

SETS = {"procedural": ["sapien"], "real": ["sapien", "pybullet"]}
"""Each set's validating simulators (as docs/synthesis/pipeline.md and refine_validate.md run them)."""


class _BuildCounter:
    """Counts the backends TrialScenes builds (every physics trial gets one) while installed."""

    def __init__(self) -> None:
        self.count, self._real = 0, TrialScenes.build

    def __enter__(self) -> _BuildCounter:
        real = self._real

        def build(scenes: TrialScenes):
            self.count += 1
            return real(scenes)

        TrialScenes.build = build
        return self

    def __exit__(self, *exc) -> None:
        TrialScenes.build = self._real


def run_once(ids: list[str], hand: str, sims: list[str], defer: bool, library: dict, folder: Path) -> dict:
    """One Stage 1 run of ``ids`` with ``hand``; its records by object id, backends built, CPU and wall seconds."""
    config = SynthesisConfig.model_validate(
        {"library": library, "validate_sims": sims, "robust": {"defer_trials": defer}}
    )
    with _BuildCounter() as built:
        cpu, wall = time.process_time(), time.perf_counter()
        run_synthesis(ids, [hand], config, folder, workers=1, progress=False)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    records = {r.object_id: r for r in open_dataset(folder)}
    return {"records": records, "backends": built.count, "cpu": cpu, "wall": wall}


def _verdicts(validations: dict) -> dict:
    return {name: replace(v, seconds=None, robust_seconds=None) for name, v in validations.items()}


def differences(a, b) -> list[str]:
    """What differs between two records of one pair beyond seconds and left-behind placements' robustness."""
    out = []
    if (a.attempt, a.strategy, a.success, a.robust) != (b.attempt, b.strategy, b.success, b.robust):
        out.append(f"kept {a.attempt}/{a.strategy}/{a.robust} vs {b.attempt}/{b.strategy}/{b.robust}")
    if [(v.refinement, v.validation, v.robust) for v in a.attempts] != [
        (v.refinement, v.validation, v.robust) for v in b.attempts
    ]:
        out.append("attempt verdicts")
    if _verdicts(a.validations) != _verdicts(b.validations):
        out.append("kept placement's verdicts")
    if a.grasp is not None and b.grasp is not None:
        if not ((a.grasp.q == b.grasp.q).all() and (a.grasp.wrist_pose == b.grasp.wrist_pose).all()):
            out.append("grasp")
    elif (a.grasp is None) != (b.grasp is None):
        out.append("grasp")
    if a.extra != b.extra:
        out.append("extra")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedural", type=int, default=len(CATEGORIES), help="procedural categories (object 000)")
    parser.add_argument("--real", type=int, default=20, help="real objects (the first N of the real set)")
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("--results", default="defer_trials", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    set_torch_threads(1)
    library_config = LibraryConfig(sources=("procedural", "pybullet", "real"))
    library = library_config.build()
    ids = {
        "procedural": [f"procedural/{c}/000" for c in list(CATEGORIES)[: args.procedural]],
        "real": [e.object_id for e in library.entries(source="real")][: args.real],
    }
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        run_once(ids["procedural"][:1], args.hands[0], ["sapien"], True, library_config.model_dump(), Path(tmp) / "w")
        for k, (group, sims) in enumerate(SETS.items()):
            if not ids[group]:
                continue
            for hand in args.hands:
                runs = {}
                for defer in (True, False) if k % 2 == 0 else (False, True):
                    folder = Path(tmp) / f"{group}-{hand}-{defer}"
                    runs[defer] = run_once(ids[group], hand, sims, defer, library_config.model_dump(), folder)
                on, off = runs[True], runs[False]
                changed = {
                    oid: d for oid in off["records"] if (d := differences(on["records"][oid], off["records"][oid]))
                }
                nulled = sum(
                    a.robustness is None and b.robustness is not None
                    for oid in off["records"]
                    for a, b in zip(on["records"][oid].attempts, off["records"][oid].attempts, strict=True)
                )
                rows.append(
                    {
                        "set": group,
                        "hand": hand,
                        "sims": sims,
                        "objects": len(ids[group]),
                        "records_differing": changed,
                        "robustness_left_null": nulled,
                        "backends": {"deferred": on["backends"], "every_trial": off["backends"]},
                        "cpu_seconds": {"deferred": on["cpu"], "every_trial": off["cpu"]},
                        "wall_seconds": {"deferred": on["wall"], "every_trial": off["wall"]},
                        "cpu_ratio": on["cpu"] / off["cpu"],
                    }
                )
                print_row(rows[-1])
    write_results(
        results,
        {
            "benchmark": "defer_trials",
            "rows": rows,
            "config": {"workers": 1, "torch_threads": 1, "sets": SETS},
            "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg()},
            "software": software_versions("sapien", "pybullet", "torch"),
            "code": code_state(),
        },
    )


def print_row(row: dict) -> None:
    if not getattr(print_row, "headed", False):
        print("| set | hand | engines | objects | records differing | backends deferred / every trial | "
              "CPU s deferred / every trial | ratio |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|")
        print_row.headed = True
    b, c = row["backends"], row["cpu_seconds"]
    print(
        f"| {row['set']} | {row['hand']} | {'+'.join(row['sims'])} | {row['objects']} | "
        f"{len(row['records_differing'])} | {b['deferred']} / {b['every_trial']} | "
        f"{c['deferred']:.1f} / {c['every_trial']:.1f} | {row['cpu_ratio']:.2f} |",
        flush=True,
    )
    for oid, what in row["records_differing"].items():
        print(f"  differs: {oid}: {', '.join(what)}")


if __name__ == "__main__":
    main()
