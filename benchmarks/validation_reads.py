"""Stage 1 with the fingertip forces read at every validation step, and as shipped: the same records, less CPU.

Validation (the nominal trial and every perturbation trial) reads the fingertip forces only where its verdict reads
them (``ges_core.synthesis.physics.validate``, module docs: until a fingertip first touches, the last closing step,
and the hold steps while the fingertip rule's share is undecided). This runs the Stage 1 pipeline
(``run_synthesis``, one process, one torch thread, SAPIEN, the defaults: robust trials on) twice over the same
objects: reading every step (``every_step``, the code before) and as shipped (``as_needed``), and compares record by
record the verdicts, the placement histories, the kept joints and wrist pose, and the CPU seconds of validation plus
the perturbation trials (``time.process_time``: a busy machine does not bend the comparison).

    python benchmarks/validation_reads.py [--procedural N] [--real N] [--hands allegro shadow] [--results NAME]

Procedural objects (object 000 of the first N categories) and real scans (the first N of the ``real`` set) are
reported apart. Prints a markdown table and writes ``benchmarks/results/NAME.json`` (default ``validation_reads``).
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path

import numpy as np
from stage1_speed import first_object, run_pipeline
from validation_early import (
    history,
    object_sets_and_config,
    options,
    run_variants,
    seconds,
    verdicts,
    write_run_results,
)

from ges_core.synthesis.physics import validate

VARIANTS = ("every_step", "as_needed")


class _EveryStep(validate._Probe):
    """The probe of the code before: it reads the fingertip forces at every step."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **{**kwargs, "every_step": True})


def run(ids: list[str], hands: list[str], config, folder: Path, variant: str) -> tuple[dict, float]:
    """{(object, hand): record} of one pipeline run and its CPU seconds."""
    probe = validate._Probe
    if variant == "every_step":
        validate._Probe = _EveryStep
    try:
        records, spent = run_pipeline(ids, hands, config, folder, "cpu")
    finally:
        validate._Probe = probe
    return {r.key: r for r in records}, spent["cpu"]


def grasp(record) -> tuple:
    """The kept grasp's joints and wrist pose (empty when none was kept), as bytes: equal means bit-identical."""
    if record.grasp is None:
        return ()
    return np.asarray(record.grasp.q).tobytes(), np.asarray(record.grasp.wrist_pose).tobytes()


def outcome(record) -> tuple:
    """What a record decides, its placement history and its grasp: equal means the same record but for timings."""
    return verdicts(record), history(record), grasp(record)


def compare(runs: dict[str, dict]) -> dict:
    """As shipped against every step, record by record."""
    keys = sorted(runs["every_step"])
    old, new = runs["every_step"], runs["as_needed"]
    same = {what.__name__: sum(what(old[k]) == what(new[k]) for k in keys) for what in (verdicts, history, grasp)}
    before = [seconds(old[k]) for k in keys]
    after = [seconds(new[k]) for k in keys]
    ratios = [a / b for a, b in zip(after, before, strict=True) if b > 0]
    return {
        "records": len(keys),
        "identical_verdicts": same["verdicts"],
        "identical_histories": same["history"],
        "identical_grasps": same["grasp"],
        "differing": [
            list(k) for k in keys if (verdicts(old[k]), history(old[k])) != (verdicts(new[k]), history(new[k]))
        ],
        "median_seconds_every_step": statistics.median(before),
        "median_seconds_as_needed": statistics.median(after),
        "sum_seconds_every_step": sum(before),
        "sum_seconds_as_needed": sum(after),
        "median_ratio": statistics.median(ratios) if ratios else None,
    }


def main() -> None:
    args = options(__doc__.splitlines()[0], "validation_reads")
    sets, config = object_sets_and_config(args)
    with tempfile.TemporaryDirectory() as tmp:
        run([first_object(sets)], args.hands[:1], config, Path(tmp) / "warm", "as_needed")  # imports, caches
        runs, cpu = run_variants(sets, args.hands, config, Path(tmp), VARIANTS, run)
    rows = {name: compare(by_variant) for name, by_variant in runs.items()}
    print(
        "\n| objects | records | same verdicts / placement histories / grasps | validation + robust CPU s per record, "
        "median: every step / as needed | median ratio | whole run CPU s: every step / as needed |"
    )
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['records']} | {r['identical_verdicts']} / {r['identical_histories']} / "
            f"{r['identical_grasps']} | {r['median_seconds_every_step']:.2f} / {r['median_seconds_as_needed']:.2f} | "
            f"{r['median_ratio']:.2f} | {cpu[f'{name}/every_step']:.1f} / {cpu[f'{name}/as_needed']:.1f} |"
        )
        for key in r["differing"]:
            print(f"  differs: {' '.join(key)}")
    write_run_results(args, "validation_reads", sets, rows, cpu_seconds=cpu)


if __name__ == "__main__":
    main()
