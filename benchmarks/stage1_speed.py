"""Stage 1 speed on one core: seconds per object for contacts, retargeting, refinement and validation.

Procedural shapes and real scanned meshes (the ``real`` set: YCB scans of 16,384 faces) separately, both
hands. One process (``workers=1``), one torch thread (``ges_core.threads``), SAPIEN refinement and
validation, the paper's single validation trial (robust trials off unless ``--robust``: they are counted
apart, ``benchmarks/stage1_robust.py`` measures them). The pipeline itself (``run_synthesis``) is timed:
the seconds are the ones its records store, so an object's refinement and validation include every
wrist placement it tried (``attempts``, default 3). Simulator setup (a fresh scene per object and hand) is
reported beside them; it is in none of the four steps.

Before timing, every object is processed (the disk cache of repaired meshes) and one object is run once
(imports, hand models): the table is the steady state of a run, not its first second. Objects without a
collision model (concave, no cached decomposition: ``ges objects prepare``) are listed and left out of
the refinement and validation columns (they fail there at once).

Also measured:

* **torch threads**: the retargeting of one chunk (8 objects, both hands) with one torch thread and with
  torch's default (one per core), with ``--load`` busy processes beside it (default 2: a loaded 2-core
  machine); joints compared bit for bit.
* **solver active set**: Allegro, 1024 reachable targets (tips only): time and share of row-iterations
  the solver skipped, at 6 and 20 iterations.

    python benchmarks/stage1_speed.py [--procedural N] [--real N] [--hands allegro shadow] [--load 2] [--robust]
        [--skip-threads] [--baseline KEY=VALUE ...] [--results NAME]

``--baseline KEY=VALUE`` (repeatable, the synthesis config's dotted keys as ``ges synth -o`` takes them, e.g.
``hand_settings.shadow.retarget.wrist_search.thumb_weight=1``): the pipeline is also timed with those values, set by
set in turn with the defaults' run (baseline first), and a third table gives each median's ratio, defaults over
baseline.

Also counted: the physics steps of each record (every backend's steps while the record's refinement and nominal
trials ran, and apart those of its perturbation trials): unlike seconds, the count does not drift with the
machine, whose speed moved by a third within one morning (docs/synthesis/refine_validate.md, "The lift's early
end").

Prints markdown tables and writes ``benchmarks/results/NAME.json`` (default ``stage1_speed``). Goal (issue 11): median
contacts + retargeting + refinement + validation <= 0.5 s per object on one core.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from ges_core.config import apply_overrides, parse_model
from ges_core.dataset import open_dataset, software_versions
from ges_core.errors import AssetError, ConfigError, SynthesisError
from ges_core.objects.library import LibraryConfig
from ges_core.objects.procedural import CATEGORIES
from ges_core.sim import SimBackend
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run import worker
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

GOAL_SECONDS = 0.5
"""Issue 11: contacts + retargeting + refinement + validation per object on one core."""
STEPS = ("contacts", "retargeting", "refinement", "validation")
CHUNK = 8
"""Objects per retargeting batch in the threads comparison (``SynthesisConfig.chunk_size``'s default)."""


# -- object sets ---------------------------------------------------------------------------------------
def object_sets(library, procedural: int, real: int) -> dict[str, list[str]]:
    """{"procedural": object 000 of the first N categories, "real": the first N real objects}, an empty set left out
    (``--real 0``); SystemExit when both are empty."""
    procedural_ids = [f"procedural/{c}/000" for c in list(CATEGORIES)[:procedural]]
    real_ids = [e.object_id for e in library.entries(source="real")][:real]
    sets = {name: ids for name, ids in (("procedural", procedural_ids), ("real", real_ids)) if ids}
    if not sets:
        raise SystemExit("no objects to run: give --procedural N or --real N above 0")
    return sets


def first_object(sets: dict[str, list[str]]) -> str:
    """The first object of the first set (:func:`object_sets`): the untimed warm-up run's."""
    return next(iter(sets.values()))[0]


def warm_up(library, ids: list[str]) -> tuple[dict[str, float], list[str]]:
    """Process every object (repair, placement: cached on disk); returns seconds per object and the ids with no
    collision model (their refinement fails at once)."""
    seconds, no_collision = {}, []
    for oid in ids:
        start = time.perf_counter()
        library.processed(oid)
        seconds[oid] = time.perf_counter() - start
        try:
            library.get(oid)
        except AssetError:
            no_collision.append(oid)
    return seconds, no_collision


# -- the pipeline, timed by its records ------------------------------------------------------------------
def run_pipeline(
    ids: list[str], hands: list[str], config: SynthesisConfig, folder: Path, clock: str, registry=None
) -> tuple[list, dict]:
    """The records of one run, its wall seconds and this process's CPU seconds (what the run cost one core,
    whatever else the machine was doing). clock "cpu": the steps' stored seconds are CPU seconds of this
    process (the pipeline's timers read ``time.perf_counter``, which is pointed at ``time.process_time`` for
    the run; one process, one torch thread: CPU time is the time on one core). registry: ``run_synthesis``'s
    (a :class:`~ges_core.synthesis.run.tasks.RegistrySpec`; None: the default registry)."""
    wall_clock = time.perf_counter
    start, cpu = wall_clock(), time.process_time()
    if clock == "cpu":
        time.perf_counter = time.process_time
    try:
        run_synthesis(ids, hands, config, folder, workers=1, registry=registry)
    finally:
        time.perf_counter = wall_clock
    return list(open_dataset(folder)), {"wall": wall_clock() - start, "cpu": time.process_time() - cpu}


# -- physics steps: a count does not drift with the machine ---------------------------------------------------
@contextlib.contextmanager
def physics_steps() -> Iterator[list[int]]:
    """Counts the physics steps every backend of this process takes inside the block (``[n]``, read after it)."""
    count, step = [0], SimBackend.step

    def counting(self, n: int = 1) -> None:
        count[0] += n
        step(self, n)

    SimBackend.step = counting
    try:
        yield count
    finally:
        SimBackend.step = step


@contextlib.contextmanager
def steps_per_record() -> Iterator[dict[tuple[str, str], dict[str, int]]]:
    """Physics steps per record of a one-process run inside the block: ``{(object, hand): {"timed": n, "robust":
    m}}``, ``robust`` the perturbation trials' (``worker.run_trial``) and ``timed`` the rest of the record's steps
    (refinement with the object's rest check, every placement's nominal trial: the steps the issue's total times)."""
    out: dict[tuple[str, str], dict[str, int]] = {}
    finish, trial = worker._finish, worker.run_trial
    robust = [0]

    def counted_trial(*args, **kwargs):
        before = count[0]
        try:
            return trial(*args, **kwargs)
        finally:
            robust[0] += count[0] - before

    def counted_finish(*args, **kwargs):
        before, robust[0] = count[0], 0
        record = finish(*args, **kwargs)
        out[record.key] = {"timed": count[0] - before - robust[0], "robust": robust[0]}
        return record

    with physics_steps() as count:
        worker._finish, worker.run_trial = counted_finish, counted_trial
        try:
            yield out
        finally:
            worker._finish, worker.run_trial = finish, trial


def per_record(record, counts: dict[tuple[str, str], dict[str, int]] | None = None) -> dict:
    """One record's seconds per step (and its physics steps when ``counts``, :func:`steps_per_record`'s, has it)."""
    counted = (counts or {}).get(record.key, {})
    steps = {name: record.steps[name].seconds for name in STEPS}
    return {
        "object": record.object_id,
        "hand": record.hand,
        "steps": steps,
        "robust": record.steps["robust"].seconds,
        "setup": sum(record.setup_seconds.values()),
        "attempts": len(record.attempts),
        "failed_step": record.failed_step,
        "failure": record.steps[record.failed_step].reason if record.failed_step else "",
        "physics_steps": counted.get("timed"),
        "robust_physics_steps": counted.get("robust"),
    }


def summarize(rows: list[dict], no_collision: set[str]) -> dict:
    """Median seconds per object of each step and of their sum (over the records that ran each step)."""

    def median(values):
        values = [v for v in values if v is not None]
        return statistics.median(values) if values else None

    physics = [r for r in rows if r["object"] not in no_collision]
    out = {name: median(r["steps"][name] for r in rows) for name in ("contacts", "retargeting")}
    out |= {name: median(r["steps"][name] for r in physics) for name in ("refinement", "validation")}
    out["total"] = median(sum(v or 0.0 for v in r["steps"].values()) for r in physics)
    out["contacts+retargeting"] = median(r["steps"]["contacts"] + (r["steps"]["retargeting"] or 0.0) for r in rows)
    out["setup"] = median(r["setup"] for r in physics)
    out["robust"] = median(r["robust"] for r in physics if r["robust"])
    out["attempts"] = median(r["attempts"] for r in physics)
    out["physics_steps"] = median(r.get("physics_steps") for r in physics)
    out["robust_physics_steps"] = median(r.get("robust_physics_steps") for r in physics if r["robust"])
    out["records"], out["timed_physics"] = len(rows), len(physics)
    return out


# -- torch threads under load -------------------------------------------------------------------------
def _spin(stop) -> None:
    """A busy process (what another user's job does to a shared core)."""
    x = 0
    while not stop.is_set():
        x += 1


def threads_under_load(library, ids: list[str], hands: list[str], load: int, repeats: int = 3) -> dict:
    """Retargeting of one chunk (the first CHUNK of ``ids`` that get contacts, both hands) with 1 thread and with
    torch's default."""
    from ges_core.registry import load_registry
    from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS, ContactConfig, generate_contacts
    from ges_core.synthesis.retarget.retargeter import GraspRetargeter
    from ges_core.synthesis.retarget.search import ObjectCloud
    from ges_core.synthesis.run.tasks import object_seed

    contacts, clouds = [], []
    for oid in ids:
        seed = object_seed(0, oid)
        points, normals = library.point_cloud(oid, 1024, seed=seed)
        try:
            result = generate_contacts(
                points, normals, ContactConfig(), object_id=oid, seed=seed, center_of_mass=LIBRARY_CENTER_OF_MASS
            )
        except SynthesisError:
            continue  # no contacts, nothing to retarget
        contacts.append(result.contacts)
        clouds.append(ObjectCloud(points, normals))
        if len(contacts) == CHUNK:
            break
    registry = load_registry()
    retargeters = {h: GraspRetargeter(registry.build_hand(h)) for h in hands}
    default = os.cpu_count() or 1
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.Event()
    spinners = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(load)]
    for p in spinners:
        p.start()
    results = {}
    try:
        time.sleep(1.0)  # let the spinners start
        for threads in (1, default):
            torch.set_num_threads(threads)
            best, joints = {}, {}
            for hand, rt in retargeters.items():
                times = []
                for _ in range(repeats):
                    start = time.perf_counter()
                    out = rt.retarget_ranked(contacts, clouds, keep=3)
                    times.append(time.perf_counter() - start)
                best[hand] = min(times) / len(contacts)
                joints[hand] = np.stack([g.q for grasps in out for g in grasps])
            results[threads] = (best, joints)
    finally:
        stop.set()
        for p in spinners:
            p.join(timeout=5)
        set_torch_threads(1)
    one, many = results[1], results[default]
    return {
        "load_processes": load,
        "cores": default,
        "objects": len(contacts),
        "seconds_per_object_1_thread": one[0],
        f"seconds_per_object_{default}_threads": many[0],
        "identical_joints": {h: bool(np.array_equal(one[1][h], many[1][h])) for h in hands},
    }


# -- solver active set --------------------------------------------------------------------------------
def solver_active_set() -> list[dict]:
    """Allegro, 1024 reachable targets: time per grasp and row-iterations skipped by the active set."""
    from retargeting import reachable_targets, slot_targets

    from ges_core.kinematics import HandKinematics
    from ges_core.registry import load_registry
    from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter

    hand = load_registry().build_hand("allegro")
    kin = HandKinematics.from_hand(hand)
    _, tips = reachable_targets(hand, kin, 1024, seed=0)
    targets = torch.as_tensor(slot_targets(hand, tips))
    rows = []
    for iterations in (6, 20):
        counted = _CountingKinematics(kin)
        solver = VectorRetargeter(hand, VectorRetargetConfig(iterations=iterations), kinematics=counted)
        best = float("inf")
        for _ in range(3):
            counted.rows.clear()
            start = time.perf_counter()
            solver.solve(targets)
            best = min(best, time.perf_counter() - start)
        passes = counted.rows[1:]  # after the start's pass: one per iteration run
        skipped = 1.0 - sum(passes) / (len(targets) * iterations)
        rows.append({"iterations": iterations, "ms_per_grasp": 1e3 * best / len(targets), "rows_skipped": skipped})
    return rows


class _CountingKinematics:
    """HandKinematics recording the batch size of each Jacobian pass."""

    def __init__(self, kin) -> None:
        self.kin, self.rows = kin, []

    def __getattr__(self, name):
        return getattr(self.kin, name)

    def points_and_jacobians(self, q, links, offsets):
        self.rows.append(len(q))
        return self.kin.points_and_jacobians(q, links, offsets)


# -- report -----------------------------------------------------------------------------------------------
def _s(value) -> str:
    return "-" if value is None else f"{value:.3f}"


def _n(value) -> str:
    return "-" if value is None else f"{value:,.0f}"


def print_pipeline_table(summary: dict) -> None:
    print(
        "\n| set | hand | records | contacts | retargeting | refinement | validation | total | goal <= 0.5 s "
        "| contacts+retargeting | setup | attempts | physics steps | robust trials' physics steps |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (group, hand), s in summary.items():
        ok = "met" if s["total"] is not None and s["total"] <= GOAL_SECONDS else "not met"
        print(
            f"| {group} | {hand} | {s['records']} ({s['timed_physics']} with physics) | {_s(s['contacts'])} | "
            f"{_s(s['retargeting'])} | {_s(s['refinement'])} | {_s(s['validation'])} | {_s(s['total'])} | {ok} | "
            f"{_s(s['contacts+retargeting'])} | {_s(s['setup'])} | {s['attempts']} | {_n(s['physics_steps'])} | "
            f"{_n(s['robust_physics_steps'])} |"
        )


def print_ratio_table(baseline: dict, summary: dict) -> None:
    """Each median of the defaults' run over the baseline's (below 1: the defaults cost less)."""
    keys = ("total", "refinement", "validation", "attempts", "physics_steps")
    print("\nratio, defaults / baseline:\n")
    print("| set | hand | " + " | ".join(keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for (group, hand), s in summary.items():
        b = baseline[(group, hand)]
        cells = [f"{s[k] / b[k]:.2f}" if s[k] is not None and b[k] else "-" for k in keys]
        print(f"| {group} | {hand} | " + " | ".join(cells) + " |")


def print_tables(threads: dict | None, solver: list[dict]) -> None:
    if threads:
        cores = threads["cores"]
        print(f"\ntorch threads, retargeting per object, {threads['load_processes']} busy processes beside it:")
        for hand, one in threads["seconds_per_object_1_thread"].items():
            many = threads[f"seconds_per_object_{cores}_threads"][hand]
            same = threads["identical_joints"][hand]
            print(
                f"  {hand}: 1 thread {one:.3f} s, {cores} threads {many:.3f} s ({many / one:.1f}x); identical: {same}"
            )
    print("\nsolver active set (Allegro, 1024 reachable targets):")
    for row in solver:
        print(f"  {row['iterations']} iterations: {row['ms_per_grasp']:.3f} ms/grasp, "
              f"{100 * row['rows_skipped']:.0f} % of row-iterations skipped")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedural", type=int, default=len(CATEGORIES), help="procedural categories (object 000)")
    parser.add_argument("--real", type=int, default=20, help="real objects (first N of the real set)")
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("--load", type=int, default=2, help="busy processes beside the torch-threads comparison")
    parser.add_argument("--robust", action="store_true", help="also run the robust trials (reported apart)")
    parser.add_argument("--skip-threads", action="store_true", help="skip the torch-threads comparison")
    parser.add_argument("--results", default="stage1_speed", help="benchmarks/results/NAME.json")
    parser.add_argument(
        "--baseline",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="also time the pipeline with this synthesis config value (repeatable) and print the ratios",
    )
    parser.add_argument(
        "--clock",
        choices=("cpu", "wall"),
        default="cpu",
        help="seconds of the steps: CPU time of this process (default: one core's cost on a shared machine) or wall",
    )
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    set_torch_threads(1)
    library_config = LibraryConfig(sources=("procedural", "pybullet", "real"))
    library = library_config.build()
    sets = object_sets(library, args.procedural, args.real)
    process_seconds, no_collision = warm_up(library, [i for ids in sets.values() for i in ids])
    data = {"library": library_config.model_dump(), "robust": {"enabled": args.robust}}
    config = parse_model(SynthesisConfig, data)
    runs = {"defaults": config}
    if args.baseline:
        try:  # a bad key stops here, not after the defaults' runs
            runs = {"baseline": parse_model(SynthesisConfig, apply_overrides(data, args.baseline)), **runs}
        except ConfigError as error:
            raise SystemExit(f"--baseline: {error}") from error
    # summaries[run][(set, hand)]: medians; records[run][set]: rows; walls[run][set]: seconds
    summaries, records, walls = ({name: {} for name in runs} for _ in range(3))
    with tempfile.TemporaryDirectory() as tmp:
        run_pipeline([first_object(sets)], args.hands, config, Path(tmp) / "warm", "wall")  # imports: untimed
        for group, ids in sets.items():
            for name, run_config in runs.items():
                with steps_per_record() as counts:
                    got, wall = run_pipeline(ids, args.hands, run_config, Path(tmp) / name / group, args.clock)
                walls[name][group] = {**wall, "cpu_per_record": wall["cpu"] / len(got)}
                rows = records[name][group] = [per_record(r, counts) for r in got]
                for hand in args.hands:
                    rows_of_hand = [r for r in rows if r["hand"] == hand]
                    summaries[name][(group, hand)] = summarize(rows_of_hand, set(no_collision))
    for name in runs:
        what = f"with {' '.join(args.baseline)}" if name == "baseline" else "defaults"
        print(f"\nmedian seconds per object ({args.clock} clock), one process, one torch thread, {what}:")
        print_pipeline_table(summaries[name])
    if args.baseline:
        print_ratio_table(summaries["baseline"], summaries["defaults"])
    threads = None
    if not args.skip_threads and "real" in sets:  # the comparison retargets real scans
        threads = threads_under_load(library, sets["real"], args.hands, args.load)
    solver = solver_active_set()
    print_tables(threads, solver)
    for group, w in walls["defaults"].items():
        print(
            f"{group}: whole run {w['wall']:.1f} s wall, {w['cpu']:.1f} s CPU = {w['cpu_per_record']:.3f} CPU s per "
            "record (everything: the four steps, simulator setup, dataset writing)"
        )
    if no_collision:
        print(f"\nno collision model (left out of refinement/validation): {', '.join(no_collision)}")
    write_results(
        results,
        {
            "benchmark": "stage1_speed",
            "goal_seconds": GOAL_SECONDS,
            "summary": [{"set": g, "hand": h, **s} for (g, h), s in summaries["defaults"].items()],
            "baseline": None
            if not args.baseline
            else {
                "overrides": args.baseline,
                "summary": [{"set": g, "hand": h, **s} for (g, h), s in summaries["baseline"].items()],
                "run_seconds": walls["baseline"],
                "records": records["baseline"],
            },
            "run_seconds": walls["defaults"],
            "process_seconds_uncached_or_cached": process_seconds,
            "no_collision_model": no_collision,
            "torch_threads": threads,
            "solver_active_set": solver,
            "records": records["defaults"],
            "config": {
                "workers": 1,
                "torch_threads": 1,
                "attempts": config.attempts,
                "robust": args.robust,
                "clock": args.clock,
            },
            "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg()},
            "software": software_versions("sapien", "torch", "trimesh"),
            "code": code_state(),
        },
    )


if __name__ == "__main__":
    main()
