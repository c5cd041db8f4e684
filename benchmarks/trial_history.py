"""Do Stage 1's validation trials depend on the trials run before them in the same scene?

The pipeline runs a placement's nominal trial and its robust trials one after another in one backend (the hand
and table stay; the object is reloaded). ``benchmarks/validation_early.py`` found placement histories that change
when an earlier trial ends sooner. This runs Stage 1 (one process, one torch thread, SAPIEN, robust validation
on) twice over the same objects: as shipped (``reused``) and with every validation trial in a fresh backend
(``fresh``: built by the registry with the same scene config, the trial run there, the backend closed), and
compares record by record the final verdicts and the placement histories (as validation_early.py does), with
the CPU seconds of each run (``time.process_time``).

    python benchmarks/trial_history.py [--procedural N] [--real N] [--hands allegro shadow]

An experiment, not a product setting: the fresh backend is swapped in here for the duration of the run. Prints a
markdown table and writes ``benchmarks/results/trial_history.json``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from validation_early import history, object_sets_and_config, options, run, verdicts, warm_up

from ges_core.dataset import software_versions
from ges_core.registry import load_registry
from ges_core.synthesis.physics import robust, validate
from ges_core.synthesis.run import worker

from _results import code_state, write_results

RESULTS = Path(__file__).parent / "results" / "trial_history.json"
CALLERS = (validate, robust, worker)
"""Modules that call ``validate_grasp`` by that name (the nominal trial: worker; the robust trials: robust)."""


def fresh_trials(registry):
    """``validate_grasp`` that ignores the scene it is given and runs the trial in a new backend like it."""
    shipped = validate.validate_grasp

    def fresh(sim, hand, obj, grasp, pregrasp_grasp, config=None, **options):
        with registry.build_sim(sim.name, sim.config) as own:
            return shipped(own, hand, obj, grasp, pregrasp_grasp, config, **options)

    return fresh


def run_variant(ids, hands, config, folder: Path, variant: str, registry) -> tuple[dict, float]:
    shipped = validate.validate_grasp
    if variant == "fresh":
        for module in CALLERS:
            module.validate_grasp = fresh_trials(registry)
    try:
        return run(ids, hands, config, folder, "early")
    finally:
        for module in CALLERS:
            module.validate_grasp = shipped


def main() -> None:
    args = options(__doc__.splitlines()[0])
    sets, config = object_sets_and_config(args)
    registry = load_registry()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        warm_up(sets, args.hands, config, Path(tmp))
        for name, ids in sets.items():
            runs, cpu = {}, {}
            for variant in ("reused", "fresh"):
                folder = Path(tmp) / name / variant
                runs[variant], cpu[variant] = run_variant(ids, args.hands, config, folder, variant, registry)
                print(f"{name} {variant}: {len(runs[variant])} records, {cpu[variant]:.1f} CPU s")
            keys = sorted(runs["reused"])
            rows[name] = {
                "records": len(keys),
                "identical_verdicts": sum(verdicts(runs["reused"][k]) == verdicts(runs["fresh"][k]) for k in keys),
                "identical_histories": sum(history(runs["reused"][k]) == history(runs["fresh"][k]) for k in keys),
                "cpu_seconds": cpu,
            }
    print("\n| objects | records | same final verdicts | same placement histories | run CPU s, reused / fresh |")
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        c = r["cpu_seconds"]
        print(
            f"| {name} | {r['records']} | {r['identical_verdicts']} | {r['identical_histories']} | "
            f"{c['reused']:.1f} / {c['fresh']:.1f} ({100 * (c['fresh'] / c['reused'] - 1):+.0f} %) |"
        )
    write_results(RESULTS, {
        "benchmark": "trial_history", "objects": sets, "hands": args.hands, "rows": rows,
        "clock": "time.process_time (one process, one torch thread)", "software": software_versions(),
        "code": code_state(),
    })  # fmt: skip


if __name__ == "__main__":
    main()
