"""Stage 1 throughput on this machine with the local process pool and with Ray, 1 and 2 workers, and the cost per task.

Rows (each a fresh dataset folder, the same objects and settings):

* ``local, in-process``: ``workers=1``, the default (no pool: the tasks run in this process);
* ``local pool, N``: a spawned process pool of N workers (N = 1 forces a pool of one);
* ``ray, N``: a Ray instance of N CPUs started here (``ray.init`` timed apart as ``start s``);
* ``ray, N, warm workers``: the same run again on that instance (a cluster's workers outlive a run: the
  second run finds torch, the engines and the hand models loaded).

Objects per second counts the whole ``run_synthesis`` call (a pool's workers start, importing torch and the
engines, on their first task: included), Ray's start (``ray.init``, which also starts its idle workers) apart and
then added in the "with Ray start" column: that column compares like with like. Every row's record files are hashed: the
last column says whether they equal the in-process row's byte for byte.

Overhead per task: ``--tasks`` tasks ``bytes(n)`` (they do nothing but return a record-sized payload: ``n`` is
a real pickled record's size) submitted at once; the seconds from the first result to the last over the number
of results after the first are the cost of one task on that executor (submit, schedule, run, return, collect;
the driver does this serially), the seconds to the first result its start-up (spawning workers; Ray's own start
is apart, as in the first table).

The machine is shared (2 cores): the 1-minute load average before and after each row is in the table and the
JSON. Typical use (a few minutes)::

    python benchmarks/scale_ray.py [--objects 6] [--hand allegro] [--tasks 300] [--results NAME]

Prints markdown tables and writes ``benchmarks/results/NAME.json`` (default NAME ``scale_ray``).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import platform
import tempfile
import time
from pathlib import Path

from ges_core.executors import LocalExecutor, make_executor
from ges_core.executors.ray_cluster import OBJECT_STORE_BYTES, import_ray

from _results import code_state, results_path, write_results

# Stage 1 (torch, the engines) is imported inside the functions that run it: a spawned pool worker imports this
# script again as its main module, and the overhead rows should time a worker's start, not this script's imports.

OBJECTS = ["procedural/cube/000", "procedural/box/000", "procedural/can/000", "procedural/sphere/000"]
OBJECTS += ["procedural/capsule/000", "procedural/cone/000", "procedural/ellipsoid/000", "procedural/wedge/000"]
SETTINGS = ["robust.enabled=false", "chunk_size=1", "library.sources=[procedural]", "library.procedural_count=1"]
"""The paper's single validation trial (perturbation trials are measured by stage1_robust.py); one object per
task, so 2 workers have tasks to share; only procedural shapes (no mesh processing before the run)."""


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def _hashes(root: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*.npz"))}


def _ray_start(workers: int) -> tuple:
    ray = import_ray()
    start = time.perf_counter()
    ray.init(num_cpus=workers, object_store_memory=OBJECT_STORE_BYTES, include_dashboard=False, log_to_driver=False)
    return ray, time.perf_counter() - start


def synthesis_rows(name: str, workers: int, ids: list[str], hand: str, config, work: Path) -> list[dict]:
    """Runs of ``ids`` on executor ``name`` (``local-here``, ``local``, ``ray``) with ``workers``: one row, and for
    Ray a second one: the same run again (another folder) on the same Ray instance, whose workers are warm."""
    from ges_core.synthesis import run_synthesis

    ray, start = _ray_start(workers) if name == "ray" else (None, 0.0)
    label = {"local-here": "local, in-process", "local": f"local pool, {workers}", "ray": f"ray, {workers}"}[name]
    rows = []
    try:
        for run in range(2 if ray else 1):
            before, t0 = _load(), time.perf_counter()
            out = work / f"{name}-{workers}-{run}"
            if name == "local":  # a pool even of one worker: LocalExecutor(in_process=False) through the pipeline
                _pool_run(ids, hand, config, out, workers)
            else:
                run_synthesis(ids, [hand], config, out, workers=workers, executor="ray" if ray else "local")
            seconds, start = time.perf_counter() - t0, start if run == 0 else 0.0
            rows.append({
                "row": label + (", warm workers" if run else ""), "executor": name, "workers": workers,
                "objects": len(ids), "seconds": round(seconds, 2), "objects_per_s": round(len(ids) / seconds, 3),
                "start_s": round(start, 2), "objects_per_s_with_start": round(len(ids) / (seconds + start), 3),
                "load_before": before, "load_after": _load(), "hashes": _hashes(out),
            })  # fmt: skip
    finally:
        if ray is not None:
            ray.shutdown()
    return rows


def _pool_run(ids: list[str], hand: str, config, out: Path, workers: int) -> None:
    """run_synthesis with a process pool even for one worker (the pipeline runs workers=1 in this process)."""
    from ges_core.synthesis import run_synthesis
    from ges_core.synthesis.run import pipeline

    real = pipeline.make_executor

    def pooled(name, *, address=None, **kwargs):
        return LocalExecutor(in_process=False, **kwargs) if "setup" in kwargs else real(name, **kwargs)

    pipeline.make_executor = pooled
    try:
        run_synthesis(ids, [hand], config, out, workers=workers)
    finally:
        pipeline.make_executor = real


def _batch(executor, n: int, payload: int) -> tuple[float, float]:
    """(seconds to the first result, seconds per result after it) of ``n`` ``bytes(payload)`` tasks."""
    t0 = time.perf_counter()
    with executor as ex:
        for _ in range(n):
            ex.submit(bytes, payload)
        stamps = []
        for done in ex.as_completed():
            assert len(done.result()) == payload
            stamps.append(time.perf_counter())
    return stamps[0] - t0, (stamps[-1] - stamps[0]) / (n - 1)


def overhead_row(name: str, workers: int, n: int, payload: int) -> dict:
    """Start-up (to the first result) and seconds per task after it, of ``n`` ``bytes(payload)`` tasks."""
    ray = _ray_start(workers)[0] if name == "ray" else None
    before = _load()
    try:
        if ray:
            first, per_task = _batch(make_executor("ray", workers=workers), n, payload)
        else:
            first, per_task = _batch(LocalExecutor(workers=workers, in_process=name == "local-here"), n, payload)
    finally:
        if ray is not None:
            ray.shutdown()
    label = {"local-here": "local, in-process", "local": f"local pool, {workers}", "ray": f"ray, {workers}"}[name]
    return {
        "row": label, "executor": name, "workers": workers, "tasks": n, "ms_per_task": round(per_task * 1e3, 3),
        "start_s": round(first, 3), "load_before": before, "load_after": _load(),
    }  # fmt: skip


def _record_payload(root: Path) -> int:
    """Bytes of one pickled GraspRecord of ``root`` (what a task sends back per object)."""
    from ges_core.dataset import open_dataset

    return len(pickle.dumps(next(iter(open_dataset(root)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--objects", type=int, default=6, help="procedural objects per row (at most 8)")
    parser.add_argument("--hand", default="allegro")
    parser.add_argument("--tasks", type=int, default=300, help="tasks of the overhead measurement (>= 2)")
    parser.add_argument("--results", default="scale_ray", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    from ges_core.config import load_config
    from ges_core.synthesis import SynthesisConfig

    ids = OBJECTS[: args.objects]
    config = load_config(SynthesisConfig, None, SETTINGS)
    rows = []
    with tempfile.TemporaryDirectory(prefix="scale_ray_") as tmp:
        for name, workers in (("local-here", 1), ("local", 1), ("local", 2), ("ray", 1), ("ray", 2)):
            rows += synthesis_rows(name, workers, ids, args.hand, config, Path(tmp))
            print(f"  {rows[-1]['row']}: {rows[-1]['seconds']} s (load {rows[-1]['load_after']})", flush=True)
        payload = _record_payload(Path(tmp) / "local-here-1-0")
    reference = rows[0]["hashes"]
    for row in rows:
        row["identical_to_in_process"] = row.pop("hashes") == reference
    kinds = (("local-here", 1), ("local", 1), ("local", 2), ("ray", 1), ("ray", 2))
    overhead = [overhead_row(name, workers, args.tasks, payload) for name, workers in kinds]
    _print(rows, overhead, payload, args.hand)
    write_results(results, _summary(args, rows, overhead, payload))


def _print(rows: list[dict], overhead: list[dict], payload: int, hand: str) -> None:
    print(f"\nStage 1, {rows[0]['objects']} procedural objects, {hand}, SAPIEN, single validation trial, 1 object/task")
    print(
        "| executor | objects/s | objects/s with Ray start | run s | Ray start s | load before -> after | identical |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['row']} | {r['objects_per_s']:.3f} | {r['objects_per_s_with_start']:.3f} | {r['seconds']:.1f} | "
            f"{r['start_s']:.1f} | "
            f"{r['load_before']} -> {r['load_after']} | {'yes' if r['identical_to_in_process'] else 'NO'} |"
        )
    print(f"\nOverhead per task ({overhead[0]['tasks']} tasks returning {payload} bytes, a pickled record)")
    print("| executor, workers | ms per task | to first result s | load before -> after |")
    print("|---|---|---|---|")
    for r in overhead:
        print(f"| {r['row']} | {r['ms_per_task']:.2f} | {r['start_s']:.2f} | {r['load_before']} -> {r['load_after']} |")


def _summary(args, rows: list[dict], overhead: list[dict], payload: int) -> dict:
    ray = import_ray()
    return {
        "what": __doc__.split("\n")[0],
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "ray_version": ray.__version__,
        "settings": {"objects": OBJECTS[: args.objects], "hand": args.hand, "overrides": SETTINGS},
        "payload_bytes": payload,
        "synthesis": rows,
        "overhead": overhead,
        "code": code_state(),
    }


if __name__ == "__main__":
    main()
