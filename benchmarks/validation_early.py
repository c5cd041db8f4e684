"""Stage 1 with and without the early end of the hold: the same verdicts, fewer physics steps.

Validation (the nominal trial and every robust trial) ends its 200-step hold as soon as the verdict cannot change
(``ges_core.synthesis.physics.validate``: not lifted but touched, or low once after the lift). This runs the
Stage 1 pipeline (``run_synthesis``, one process, one torch thread, SAPIEN, robust validation on: the defaults)
three times over the same objects: with every hold step (``full``), again so (``full_again``: the control, the
pipeline repeats itself exactly in one process), and as shipped (``early``). It compares record by record the
verdicts (each step's, the failed step, robust and the robustness score), the placement histories (each
placement's refinement / validation / robust verdicts) and the seconds of validation and of the robust trials.
A trial's own verdict does not depend on the early end (the tests check it); a later trial in the same scene can,
through the physics state the skipped steps would have left (not traced; the scene, hand and table are reused
from trial to trial), so marginal grasps may get other verdicts: the table counts them. Seconds are CPU seconds of this
process (``time.process_time``; one process, one torch thread), so a busy machine does not bend the comparison.

    python benchmarks/validation_early.py [--procedural N] [--real N] [--hands allegro shadow]

Procedural objects (object 000 of the first N categories) and real scans (the first N of the ``real`` set)
are reported apart. Prints a markdown table and writes ``benchmarks/results/validation_early.json``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from stage1_speed import object_sets, run_pipeline

from ges_core.dataset import software_versions
from ges_core.objects.library import LibraryConfig
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.physics import validate
from ges_core.threads import set_torch_threads

from _results import code_state, write_results

RESULTS = Path(__file__).parent / "results" / "validation_early.json"
VARIANTS = ("full", "full_again", "early")


def run(ids: list[str], hands: list[str], config: SynthesisConfig, folder: Path, variant: str) -> tuple[dict, float]:
    """{(object, hand): record} of one pipeline run and its CPU seconds (``stage1_speed.run_pipeline``, CPU clock:
    the records' step seconds are CPU seconds of this process); ``full`` runs every hold step."""
    settled = validate._settled
    if variant.startswith("full"):
        validate._settled = lambda *_: False  # never settled: the hold runs all its steps
    try:
        records, seconds = run_pipeline(ids, hands, config, folder, "cpu")
    finally:
        validate._settled = settled
    return {r.key: r for r in records}, seconds["cpu"]


def options(description: str) -> argparse.Namespace:
    """The object-set and hand options of this benchmark and ``trial_history.py``; one torch thread set."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--procedural", type=int, default=12, help="object 000 of the first N categories")
    parser.add_argument("--real", type=int, default=10, help="the first N real scans (extra [real])")
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    args = parser.parse_args()
    set_torch_threads(1)
    return args


def object_sets_and_config(args: argparse.Namespace) -> tuple[dict[str, list[str]], SynthesisConfig]:
    """``stage1_speed.object_sets`` of the options, and Stage 1's default config over that library."""
    library = LibraryConfig(sources=("procedural", "real"), decompose=True)
    return object_sets(library.build(), args.procedural, args.real), SynthesisConfig(library=library)


def warm_up(sets: dict[str, list[str]], hands: list[str], config: SynthesisConfig, tmp: Path) -> None:
    """One object with one hand, so imports and caches are not in the first timed run."""
    run([sets["procedural"][0]], hands[:1], config, tmp / "warm", "early")


def verdicts(record) -> tuple:
    """What the record decides (not its timings): each step's verdict, the failed step, success, robustness."""
    steps = tuple((name, s.ok, s.reason) for name, s in sorted(record.steps.items()))
    return steps, record.failed_step, record.success, record.robust, record.robustness


def history(record) -> tuple:
    """Every placement's refinement, validation and robust verdicts, in order."""
    return tuple(record.attempts)


def seconds(record) -> float:
    """Validation (every placement's nominal trial) plus the robust trials, CPU seconds."""
    return (record.steps["validation"].seconds or 0.0) + (record.steps["robust"].seconds or 0.0)


def compare(runs: dict[str, dict]) -> dict:
    """Early against full, record by record; ``full_again`` (a second full run) is the control: the pipeline is
    deterministic in one process, so what differs between full and early comes from the skipped steps."""
    keys = sorted(runs["full"])

    def same(a: str, b: str, what) -> list:
        return [k for k in keys if what(runs[a][k]) == what(runs[b][k])]

    full = [seconds(runs["full"][k]) for k in keys]
    early = [seconds(runs["early"][k]) for k in keys]
    ratios = [e / f for e, f in zip(early, full, strict=True) if f > 0]
    kept = same("full", "early", verdicts)
    return {
        "records": len(keys),
        "control_identical_verdicts": len(same("full", "full_again", verdicts)),
        "control_identical_histories": len(same("full", "full_again", history)),
        "identical_verdicts": len(kept),
        "identical_histories": len(same("full", "early", history)),
        "differing_verdicts": [
            {"record": list(k), "full": _short(runs["full"][k]), "early": _short(runs["early"][k])}
            for k in keys
            if k not in kept
        ],
        "median_seconds_full": statistics.median(full),
        "median_seconds_early": statistics.median(early),
        "sum_seconds_full": sum(full),
        "sum_seconds_early": sum(early),
        "median_ratio_early_to_full": statistics.median(ratios) if ratios else None,
    }


def _short(record) -> dict:
    return {
        "validated": record.steps["validation"].ok,
        "robust": record.robust,
        "robustness": record.robustness,
        "attempts": len(record.attempts),
    }


def run_variants(sets: dict[str, list[str]], hands: list[str], config, tmp: Path, variants, run) -> tuple[dict, dict]:
    """Every object set run once per variant, in order, with ``run(ids, hands, config, folder, variant)`` (which
    returns ``({key: record}, CPU s)``): ``({set: {variant: {key: record}}}, {"set/variant": CPU s})``, a line
    printed per run."""
    runs, cpu = {}, {}
    for name, ids in sets.items():
        runs[name] = {}
        for variant in variants:
            label = f"{name}/{variant}"
            runs[name][variant], cpu[label] = run(ids, hands, config, tmp / name / variant, variant)
            print(f"{name} {variant}: {len(runs[name][variant])} records, {cpu[label]:.1f} CPU s")
    return runs, cpu


def main() -> None:
    args = options(__doc__.splitlines()[0])
    sets, config = object_sets_and_config(args)
    with tempfile.TemporaryDirectory() as tmp:
        warm_up(sets, args.hands, config, Path(tmp))
        runs, cpu = run_variants(sets, args.hands, config, Path(tmp), VARIANTS, run)
    rows = {name: compare(by_variant) for name, by_variant in runs.items()}
    print(
        "\n| objects | records | same verdicts: full again / early | same placement histories: full again / early "
        "| validation + robust s, median full / early | median ratio early/full | run CPU s full / early |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['records']} | {r['control_identical_verdicts']} / {r['identical_verdicts']} | "
            f"{r['control_identical_histories']} / {r['identical_histories']} | {r['median_seconds_full']:.2f} / "
            f"{r['median_seconds_early']:.2f} | {r['median_ratio_early_to_full']:.2f} | "
            f"{cpu[f'{name}/full']:.1f} / {cpu[f'{name}/early']:.1f} |"
        )
        for d in r["differing_verdicts"]:
            print(f"  {' '.join(d['record'])}: full {d['full']}, early {d['early']}")
    write_results(RESULTS, {
        "benchmark": "validation_early", "objects": sets, "hands": args.hands, "rows": rows, "cpu_seconds": cpu,
        "clock": "time.process_time (one process, one torch thread)", "software": software_versions(),
        "code": code_state(),
    })  # fmt: skip


if __name__ == "__main__":
    main()
