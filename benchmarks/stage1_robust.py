"""Robust validation on the demo set: per hand x validating simulator, validated (the paper's single trial),
robust (every perturbation held), mean robustness, cross-engine agreement and the perturbation trials' cost.

Runs Stage 1 on the built-in demo objects (``DEMO_OBJECTS``) for both hands, refining in SAPIEN and validating
each grasp in SAPIEN and PyBullet, robust validation on (its defaults: ``RobustConfig``), ``--workers`` processes
(one torch thread each). ``--retry both`` also runs it with ``robust.retry=false`` (the attempt loop stops at
the first nominal pass) to measure what going on to the next placement buys; a retry run's records already
say it exactly (``robust_primary_if_stopped_at_first_nominal_pass``: the first nominally passing attempt's
robust verdict; the attempts before it ran the same way), so one run is enough when the code does not change
between two. ``--dataset DIR`` summarizes an
existing run instead (e.g. ``ges demo -o "synthesis.validate_sims=[sapien,pybullet]"``'s ``DIR/dataset``).
Prints a table and writes ``benchmarks/results/NAME.json`` (``--results``, default ``stage1_robust``).

    python benchmarks/stage1_robust.py [--objects N] [--workers 2] [--retry on|both] [--dataset DIR ...]
        [--note TEXT] [--results NAME]
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from ges_core.dataset import open_dataset, software_versions
from ges_core.dataset.summary import agreement, sim_stats
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.demo import DEMO_OBJECTS

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=len(DEMO_OBJECTS), help="first N demo objects")
    parser.add_argument("--hands", nargs="+", default=["shadow", "allegro"])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--retry", choices=["on", "both"], default="on")
    parser.add_argument("--dataset", nargs="+", type=Path, help="summarize these finished runs (no new run)")
    parser.add_argument("--note", default="", help="how the --dataset runs were made (command, commit), stored")
    parser.add_argument("--results", default="stage1_robust", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    runs = {}
    if args.dataset:
        for folder in args.dataset:
            runs[str(folder)] = _summary(
                list(open_dataset(folder)), None, SynthesisConfig.of_dataset(open_dataset(folder))
            )
    else:
        for retry in [True] if args.retry == "on" else [True, False]:
            runs[f"retry={retry}"] = _run(list(DEMO_OBJECTS[: args.objects]), args, retry)
    for name, summary in runs.items():
        print(f"\n{name}:\n" + _format(summary))
    machine = {"platform": platform.platform(), "workers": args.workers}
    versions = software_versions("sapien", "pybullet")
    write_results(
        results, {"runs": runs, "note": args.note, "machine": machine, "versions": versions, "code": code_state()}
    )


def _run(ids: list[str], args, retry: bool) -> dict:
    config = SynthesisConfig.model_validate({"validate_sims": ["sapien", "pybullet"], "robust": {"retry": retry}})
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        run_synthesis(ids, args.hands, config, Path(tmp) / "ds", workers=args.workers, progress=True)
        wall = time.perf_counter() - start
        return _summary(list(open_dataset(Path(tmp) / "ds")), wall, config)


def _summary(records, wall: float | None, config: SynthesisConfig) -> dict:
    rows = []
    for s in sim_stats(records):
        mine = [r for r in records if r.hand == s.hand and s.simulator in r.validations]
        trials = [r.validations[s.simulator].robust_seconds for r in mine if r.validations[s.simulator].trials]
        trials = [t for t in trials if t is not None]
        rows.append({
            "hand": s.hand, "simulator": s.simulator, "objects": s.records, "validated": s.validated,
            "robust": s.robust, "mean_robustness": s.mean_robustness, "trial_failures": s.trial_failures,
            "trial_seconds_per_grasp_median": float(np.median(trials)) if trials else None,
            "trial_seconds_per_object_mean": float(np.sum(trials)) / s.records if s.records else None,
        })  # fmt: skip
    per_object = {}
    for hand in sorted({r.hand for r in records}):
        mine = [r for r in records if r.hand == hand]
        robust = [r.steps["robust"].seconds for r in mine if r.steps["robust"].seconds is not None]
        total = [r.total_seconds for r in mine if r.total_seconds is not None]
        per_object[hand] = {
            "robust_primary": sum(r.robust for r in mine),
            "robust_primary_if_stopped_at_first_nominal_pass": sum(_first_pass_robust(r) for r in mine),
            "robust_step_seconds_mean_all_attempts": float(np.mean(robust)) if robust else None,
            "total_seconds_median": float(np.median(total)) if total else None,
            "attempts_tried_mean": float(np.mean([len(r.attempts) for r in mine])),
        }
    return {
        "rows": rows,
        "agreement": agreement(records),
        "per_object": per_object,
        "wall_seconds": wall,
        "trials_per_grasp": config.robust.trial_count,
        "robust_config": config.robust.model_dump(mode="json"),
    }


def _first_pass_robust(record) -> bool:
    """Whether the record would be robust had the attempt loop stopped at the first nominal pass
    (``robust.retry=false``): that attempt's robust verdict. Exact: the attempts before it ran the same way."""
    first = next((a for a in record.attempts if a.validation == "ok"), None)
    return first is not None and first.robust == "ok"


def _format(summary: dict) -> str:
    head = "| hand | sim | validated (single trial) | robust | mean robustness | trial s per passing grasp (median) |"
    lines = [head, "|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        score = "-" if r["mean_robustness"] is None else f"{r['mean_robustness']:.3f}"
        secs = "-" if r["trial_seconds_per_grasp_median"] is None else f"{r['trial_seconds_per_grasp_median']:.2f}"
        counts = f"{r['validated']}/{r['objects']} | {r['robust']}/{r['objects']}"
        lines.append(f"| {r['hand']} | {r['simulator']} | {counts} | {score} | {secs} |")
    for hand, a in summary["agreement"].items():
        lines.append(
            f"agreement {hand}: single trial {a['single']}/{a['grasps']}, robust {a['robust']}/{a['robust_grasps']}"
        )
    for hand, p in summary["per_object"].items():
        lines.append(f"{hand}: {p}")
    if summary["wall_seconds"] is not None:
        lines.append(f"wall {summary['wall_seconds']:.1f} s")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
