"""Stage 1 with and without the early ends of validation: the same verdicts, fewer physics steps.

Validation (the nominal trial and every robust trial) ends its lift as soon as a touched object is lost (``lost_lag``
below the wrist target's rise) and its 200-step hold as soon as the verdict cannot change
(``ges_core.synthesis.physics.validate``: not lifted but touched, or low once after the lift). This runs the
Stage 1 pipeline (``run_synthesis``, one process, one torch thread, SAPIEN, robust validation on: the defaults)
four times over the same objects: with every lift and hold step (``full``), again so (``full_again``: the control,
the pipeline repeats itself exactly in one process), with the hold's early end only (``hold_early``: as shipped
before 6 December 2026) and as shipped (``early``). It compares record by record with ``full`` the verdicts (each
step's, the failed step, robust and the robustness score), the placement histories (each placement's refinement /
validation / robust verdicts) and the seconds of validation and of the robust trials, and gives per hand the
issue's total (contacts + retargeting + refinement + validation per object, median). The hold's end is exact (a
trial's verdict does not depend on it, the tests check it); the lift's is not by construction (a lost object
could climb back within the hand), so this measures it. Every trial runs in a backend of its own, so a skipped
step changes nothing in the later trials. Seconds are CPU seconds of this process (``time.process_time``; one
process, one torch thread), so a busy machine does not bend the comparison.

    python benchmarks/validation_early.py [--procedural N] [--real N] [--hands allegro shadow] [--results NAME]

Procedural objects (object 000 of the first N categories) and real scans (the first N of the ``real`` set)
are reported apart. Prints a markdown table and writes ``benchmarks/results/NAME.json`` (default
``validation_early``).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from stage1_speed import STEPS, first_object, object_sets, physics_steps, run_pipeline

from ges_core.dataset import software_versions
from ges_core.objects.library import LibraryConfig
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.physics import validate
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

VARIANTS = ("full", "full_again", "hold_early", "early")


def run(ids: list[str], hands: list[str], config: SynthesisConfig, folder: Path, variant: str) -> tuple[dict, float]:
    """{(object, hand): record} of one pipeline run and its CPU seconds (``stage1_speed.run_pipeline``, CPU clock:
    the records' step seconds are CPU seconds of this process); ``full`` runs every lift and hold step,
    ``hold_early`` every lift step."""
    settled = validate._settled
    if variant.startswith("full"):
        validate._settled = lambda *_: False  # never settled: the hold runs all its steps
    if variant != "early":
        config = config.model_copy(update={"validate_": config.validate_.model_copy(update={"lost_lag": None})})
    try:
        records, seconds = run_pipeline(ids, hands, config, folder, "cpu")
    finally:
        validate._settled = settled
    return {r.key: r for r in records}, seconds["cpu"]


def options(description: str, results: str) -> argparse.Namespace:
    """The object-set, hand and ``--results NAME`` (default ``results``) options of this benchmark,
    ``trial_history.py`` and ``validation_reads.py``; one torch thread set."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--procedural", type=int, default=12, help="object 000 of the first N categories")
    parser.add_argument("--real", type=int, default=10, help="the first N real scans (extra [real])")
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("--results", default=results, help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results_path(args.results)  # a bad name stops here, not after the runs
    set_torch_threads(1)
    return args


def write_run_results(
    args: argparse.Namespace, benchmark: str, sets: dict[str, list[str]], rows: dict, **extra
) -> None:
    """``benchmarks/results/NAME.json`` (``args.results``) of a benchmark built on :func:`options`: its object sets,
    hands and rows, ``extra`` after them, the clock, software versions and code state."""
    write_results(results_path(args.results), {
        "benchmark": benchmark, "objects": sets, "hands": args.hands, "rows": rows, **extra,
        "clock": "time.process_time (one process, one torch thread)", "software": software_versions(),
        "code": code_state(),
    })  # fmt: skip


def object_sets_and_config(args: argparse.Namespace) -> tuple[dict[str, list[str]], SynthesisConfig]:
    """``stage1_speed.object_sets`` of the options, and Stage 1's default config over that library."""
    library = LibraryConfig(sources=("procedural", "real"), decompose=True)
    return object_sets(library.build(), args.procedural, args.real), SynthesisConfig(library=library)


def warm_up(sets: dict[str, list[str]], hands: list[str], config: SynthesisConfig, tmp: Path) -> None:
    """One object with one hand, so imports and caches are not in the first timed run."""
    run([first_object(sets)], hands[:1], config, tmp / "warm", "early")


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


def total(record) -> float:
    """The issue's total: contacts + retargeting + refinement + validation, CPU seconds."""
    return sum(record.steps[name].seconds or 0.0 for name in STEPS)


def compare(runs: dict[str, dict]) -> dict:
    """Each variant against full, record by record; ``full_again`` (a second full run) is the control: the pipeline
    is deterministic in one process, so what differs between full and another variant comes from the skipped
    steps."""
    keys = sorted(runs["full"])
    hands = sorted({k[1] for k in keys})

    def same(a: str, b: str, what) -> list:
        return [k for k in keys if what(runs[a][k]) == what(runs[b][k])]

    out = {"records": len(keys)}
    for variant in runs:
        kept = same("full", variant, verdicts)
        per_record = [seconds(runs[variant][k]) for k in keys]
        out[variant] = {
            "identical_verdicts": len(kept),
            "identical_histories": len(same("full", variant, history)),
            "differing_verdicts": [
                {"record": list(k), "full": _short(runs["full"][k]), variant: _short(runs[variant][k])}
                for k in keys
                if k not in kept
            ],
            "median_seconds": statistics.median(per_record),
            "sum_seconds": sum(per_record),
            "median_total_by_hand": {
                hand: statistics.median(total(runs[variant][k]) for k in keys if k[1] == hand) for hand in hands
            },
        }
    full = [seconds(runs["full"][k]) for k in keys]
    for variant in ("hold_early", "early"):
        ratios = [seconds(runs[variant][k]) / f for k, f in zip(keys, full, strict=True) if f > 0]
        out[variant]["median_ratio_to_full"] = statistics.median(ratios) if ratios else None
    return out


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
    args = options(__doc__.splitlines()[0], "validation_early")
    sets, config = object_sets_and_config(args)
    with tempfile.TemporaryDirectory() as tmp:
        warm_up(sets, args.hands, config, Path(tmp))
        steps = {}

        def counted(ids, hands, config, folder, variant):
            with physics_steps() as count:
                out = run(ids, hands, config, folder, variant)
            steps[f"{folder.parent.name}/{variant}"] = count[0]
            return out

        runs, cpu = run_variants(sets, args.hands, config, Path(tmp), VARIANTS, counted)
    rows = {name: compare(by_variant) for name, by_variant in runs.items()}
    print(
        "\n| objects | records | variant | same verdicts as full | same placement histories | validation + robust "
        "s per record, median | ratio to full, median | total s per object by hand, median | run CPU s | physics "
        "steps |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        for variant in VARIANTS:
            v = r[variant]
            ratio = v.get("median_ratio_to_full")
            totals = ", ".join(f"{hand} {t:.3f}" for hand, t in v["median_total_by_hand"].items())
            print(
                f"| {name} | {r['records']} | {variant} | {v['identical_verdicts']} | {v['identical_histories']} | "
                f"{v['median_seconds']:.2f} | {'' if ratio is None else f'{ratio:.2f}'} | {totals} | "
                f"{cpu[f'{name}/{variant}']:.1f} | {steps[f'{name}/{variant}']:,} |"
            )
            for d in v["differing_verdicts"]:
                print(f"  {variant}: {' '.join(d['record'])}: full {d['full']}, {variant} {d[variant]}")
    write_run_results(args, "validation_early", sets, rows, cpu_seconds=cpu, physics_steps=steps)


if __name__ == "__main__":
    main()
