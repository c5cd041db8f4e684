"""Stage 1 over the whole built-in library: a ContactGrasp-scale dataset, counted per split and per category.

Every object of the library (every procedural category at its configured count, pybullet_data's objects,
the ``real`` YCB set), both hands, ``--workers`` processes (default 2, one torch thread each), robust
validation on (the default). The dataset folder is resumable: run the same command again after a kill and
it goes on where it stopped (stored (object, hand) pairs are skipped); ``--fresh`` starts over. Concave
meshes are decomposed on the fly (CoACD, cached by mesh hash; near-convex scans use their hull).

    python benchmarks/stage1_dataset.py [--out runs/stage1_dataset] [--workers 2] [--limit N] [--fresh]
        [--results NAME]
    python benchmarks/stage1_dataset.py --sources procedural     # part of the library (its own results file)
    python benchmarks/stage1_dataset.py --hands shadow           # one hand (its own results file and folder)
    python benchmarks/stage1_dataset.py --summary-only          # count what is stored, run nothing

Per split and per category (and per hand): records, validated (the paper's single trial), robust (every
perturbation trial held), median seconds per object (contacts + retargeting + refinement + validation, the
nominal trial; robust trials apart). Prints markdown and writes ``benchmarks/results/NAME.json``, by default
NAME ``stage1_dataset`` (also after ``--summary-only``, marked incomplete while pairs are missing); with ``--sources``
naming part of the library, ``stage1_dataset_<sources>.json`` instead, and the dataset folder defaults to
``runs/stage1_dataset_<sources>``: the splits are drawn over the objects listed (the unseen categories are about
10 % of them), so a part's split labels differ from the whole library's and the two must not share a folder. With
``--hands`` naming one hand, ``_<hand>`` is added to both names; the splits do not depend on the hands, so its rows
compare with the whole run's. ``--results NAME`` replaces the results file's name (not the folder's). The wall
time is the sum over the runs that wrote the folder (each run appends itself to ``<out>.runs.json`` beside it).

Paper: 773 objects in 82 categories (563 train, 132 unseen-object, 78 unseen-category).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from collections import defaultdict
from pathlib import Path
from statistics import median

from ges_core.dataset import open_dataset, software_versions
from ges_core.objects.library import LibraryConfig
from ges_core.paths import atomic_write_text
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

HANDS = ("allegro", "shadow")
SOURCES = ("procedural", "pybullet", "real")
RUNS_SUFFIX = ".runs.json"
"""``<out>.runs.json`` beside the dataset folder: each run's wall time, so a resumed dataset's total adds up."""
PAPER = {"objects": 773, "categories": 82, "train": 563, "unseen_object": 132, "unseen_category": 78}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="dataset folder, resumed (default runs/stage1_dataset…)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--limit", type=int, default=None, help="only the first N objects (a smoke run)")
    parser.add_argument("--fresh", action="store_true", help="delete --out first")
    parser.add_argument("--summary-only", action="store_true", help="count the stored records, run nothing")
    parser.add_argument(
        "--allow-config-change", action="store_true", help="resume --out although it was written with other settings"
    )
    parser.add_argument("--sources", nargs="+", choices=SOURCES, default=list(SOURCES), help="library sources")
    parser.add_argument("--hands", nargs="+", choices=HANDS, default=list(HANDS), help="hands")
    parser.add_argument(
        "--results", default=None, help="benchmarks/results/NAME.json (default stage1_dataset[_<sources>][_<hand>])"
    )
    args = parser.parse_args()
    set_torch_threads(1)
    sources = tuple(s for s in SOURCES if s in args.sources)
    hands = tuple(h for h in HANDS if h in args.hands)
    part = ("" if sources == SOURCES else "_" + "-".join(sources)) + ("" if hands == HANDS else "_" + "-".join(hands))
    results = results_path(args.results or f"stage1_dataset{part}")  # a bad name stops here, not after the run
    args.out = args.out or Path(f"runs/stage1_dataset{part}")
    config = SynthesisConfig(library=LibraryConfig(sources=sources, decompose=True))
    objects = config.library.build().list()
    objects = objects if args.limit is None else objects[: args.limit]
    if args.fresh and args.out.exists():
        if any(args.out.iterdir()) and not (args.out / "manifest.json").is_file():
            raise SystemExit(f"--fresh deletes --out, but {args.out} holds no dataset (no manifest.json): pick another")
        shutil.rmtree(args.out)
    if not args.summary_only:
        start, written = time.perf_counter(), []
        try:  # a stopped run (Ctrl-C) keeps its records and logs its time too; a SIGKILL loses only the time
            ids = [o.object_id for o in objects]
            run_synthesis(
                ids, hands, config, args.out, workers=args.workers, progress=True, on_record=written.append,
                allow_config_change=args.allow_config_change,
            )  # fmt: skip
        finally:
            _log_run(args.out, time.perf_counter() - start, args.workers, len(written))
    runs = _runs(args.out)
    wall = sum(r["seconds"] for r in runs)
    wanted = {(o.object_id, h) for o in objects for h in hands}
    records = [r for r in open_dataset(args.out) if r.key in wanted]
    tables = {by: count(records, by) for by in ("split", "category")}
    for by, rows in tables.items():
        print(f"\n### per {by}\n" + format_rows(by, rows))
    done = len(records) == len(wanted)
    print(f"\n{len(records)} of {len(wanted)} (object, hand) records stored{'' if done else ' (incomplete)'}")
    workers = ", ".join(str(r["workers"]) for r in runs)
    print(f"wall time: {wall / 60:.1f} min in {len(runs)} run(s) ({workers} workers)")
    write_results(results, _data(objects, records, wanted, tables, runs, args) | {"sources": list(sources)})


def _runs_file(out: Path) -> Path:
    return out.with_name(out.name + RUNS_SUFFIX)


def _runs(out: Path) -> list[dict]:
    """The runs that wrote ``out`` (``<out>.runs.json``): seconds, workers and records written by each."""
    path = _runs_file(out)
    return json.loads(path.read_text())["runs"] if path.is_file() else []


def _log_run(out: Path, seconds: float, workers: int, written: int) -> None:
    """Append this run to ``<out>.runs.json`` (atomically), so a resumed dataset's wall time adds up."""
    runs = [*_runs(out), {"seconds": seconds, "workers": workers, "records_written": written}]
    atomic_write_text(_runs_file(out), json.dumps({"runs": runs}, indent=1) + "\n")


def count(records: list, by: str) -> dict[str, dict[str, dict]]:
    """{group: {hand: {records, validated, robust, median_seconds}}} with ``by`` = split or category."""
    groups: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        groups[getattr(r, by)][r.hand].append(r)
        groups["all"][r.hand].append(r)
    return {g: {h: _cell(rs) for h, rs in sorted(per_hand.items())} for g, per_hand in sorted(groups.items())}


def _cell(records: list) -> dict:
    seconds = [r.total_seconds for r in records if r.total_seconds is not None]
    return {
        "records": len(records),
        "validated": sum(r.steps["validation"].ok for r in records),  # the nominal trial (record.success needs robust)
        "robust": sum(r.robust for r in records),
        "median_seconds": median(seconds) if seconds else None,
    }


def format_rows(by: str, rows: dict[str, dict[str, dict]]) -> str:
    """A markdown table: one line per group and hand."""
    lines = [f"| {by} | hand | records | validated | robust | median s/object |", "|---|---|---|---|---|---|"]
    for group, per_hand in rows.items():
        for hand, c in per_hand.items():
            sec = "-" if c["median_seconds"] is None else f"{c['median_seconds']:.2f}"
            n = c["records"]
            lines.append(
                f"| {group} | {hand} | {n} | {c['validated']} ({100 * c['validated'] / n:.0f} %) "
                f"| {c['robust']} ({100 * c['robust'] / n:.0f} %) | {sec} |"
            )
    return "\n".join(lines)


def _data(objects, records, wanted, tables, runs, args) -> dict:
    categories = sorted({o.category for o in objects})
    splits = defaultdict(int)
    for o in objects:
        splits[o.split] += 1
    return {
        "objects": len(objects),
        "categories": len(categories),
        "category_names": categories,
        "objects_per_split": dict(splits),
        "hands": sorted({hand for _, hand in wanted}),
        "records_stored": len(records),
        "records_wanted": len(wanted),
        "complete": len(records) == len(wanted),
        "per_split": tables["split"],
        "per_category": tables["category"],
        "wall_seconds": sum(r["seconds"] for r in runs),
        "runs": runs,
        "seconds_meaning": "median over records of contacts + retargeting + refinement + validation (nominal trial)",
        "paper": PAPER,
        "machine": {"platform": platform.platform()},
        "versions": software_versions("sapien"),
        "code": code_state(),
    }


if __name__ == "__main__":
    main()
