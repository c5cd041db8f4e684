"""Do Stage 1's validation trials depend on the trials run before them in the same scene?

Stage 1 runs every physics trial (a refinement, a nominal validation, each perturbation trial) in a backend of
its own (``TrialScenes``). Before, one backend per (object, hand, simulator) served them all, one after another
(the hand and table stayed; the object was reloaded), and ``benchmarks/validation_early.py`` found placement
histories that changed when an earlier trial ended sooner. This runs Stage 1 (one process, one torch thread,
SAPIEN, robust validation on) twice over the same objects: with one backend reused for every trial of an
(object, hand) pair as before (``reused``: ``TrialScenes.open`` swapped for the duration of the run) and as
shipped (``fresh``), and compares record by record the final verdicts and the placement histories (as
validation_early.py does), with the CPU seconds of each run (``time.process_time``).

    python benchmarks/trial_history.py [--procedural N] [--real N] [--hands allegro shadow] [--results NAME]

Prints a markdown table and writes ``benchmarks/results/NAME.json`` (default ``trial_history``).
"""

from __future__ import annotations

import tempfile
from contextlib import contextmanager
from pathlib import Path

from validation_early import history, object_sets_and_config, options, run, verdicts, warm_up, write_run_results

from ges_core.synthesis.physics import scene


@contextmanager
def reused_backends():
    """While open, each ``TrialScenes`` hands out one backend for all its trials (the old behaviour); closed after."""
    shipped, kept = scene.TrialScenes.open, {}

    @contextmanager
    def open_reused(self):
        if id(self) not in kept:
            kept[id(self)] = (self, self.build())  # the TrialScenes kept alive too, so its id is not reused
        yield kept[id(self)][1]

    scene.TrialScenes.open = open_reused
    try:
        yield
    finally:
        scene.TrialScenes.open = shipped
        for _, sim in kept.values():
            sim.close()


def run_variant(ids, hands, config, folder: Path, variant: str) -> tuple[dict, float]:
    if variant == "reused":
        with reused_backends():
            return run(ids, hands, config, folder, "early")
    return run(ids, hands, config, folder, "early")


def main() -> None:
    args = options(__doc__.splitlines()[0], "trial_history")
    sets, config = object_sets_and_config(args)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        warm_up(sets, args.hands, config, Path(tmp))
        for name, ids in sets.items():
            runs, cpu = {}, {}
            for variant in ("reused", "fresh", "fresh_again"):
                folder = Path(tmp) / name / variant
                runs[variant], cpu[variant] = run_variant(ids, args.hands, config, folder, variant)
                print(f"{name} {variant}: {len(runs[variant])} records, {cpu[variant]:.1f} CPU s")
            keys = sorted(runs["reused"])
            rows[name] = {"records": len(keys), "cpu_seconds": cpu}
            for other in ("reused", "fresh_again"):  # against the shipped run: the old behaviour, and a control
                rows[name][other] = {
                    "identical_verdicts": sum(verdicts(runs[other][k]) == verdicts(runs["fresh"][k]) for k in keys),
                    "identical_histories": sum(history(runs[other][k]) == history(runs["fresh"][k]) for k in keys),
                }
    print("\n| objects | records | same final verdicts as fresh (reused / fresh again) | same placement histories "
          "(reused / fresh again) | run CPU s, reused / fresh |")  # fmt: skip
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        c, old, again = r["cpu_seconds"], r["reused"], r["fresh_again"]
        print(
            f"| {name} | {r['records']} | {old['identical_verdicts']} / {again['identical_verdicts']} | "
            f"{old['identical_histories']} / {again['identical_histories']} | "
            f"{c['reused']:.1f} / {c['fresh']:.1f} ({100 * (c['fresh'] / c['reused'] - 1):+.0f} %) |"
        )
    write_run_results(args, "trial_history", sets, rows)


if __name__ == "__main__":
    main()
