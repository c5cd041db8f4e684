"""Gate inference time per object on one CPU core: CurveNet, PointNet++ and the centroid baseline, old code beside new.

For each gate (its registered default settings) at 1024 and 4096 input points: the time of one
``gate.predict`` call on one object's cloud (batch 1, the input checks included), median over repeats,
wall clock and the process's CPU time, with ``torch.set_num_threads(1)``. The clouds are real: farthest
points of procedural library objects' surfaces, object frame, metres. Network weights are a seeded
initialization (inference cost does not depend on their values); the centroid gate is fitted to a
size rule on the same objects (its cost is its feature computation). Also the per-object time when 32
objects go in one call (how ``ges evaluate`` would call it).

Old against new, in the same run: CurveNet and PointNet++ are also built from the code of git revision
``--baseline`` (benchmarks/_gate_baseline.py: the last commit before the inference rewrite), given the
same weights, and timed call by call in turn with today's on the same cloud, so that all meet the same
machine load: "old" is that code with its own default settings (the gate as it was), "old code, new
settings" the same function as today's (the table gives the largest difference between their logits on
the objects: the rewrite computes the same function), so the two speedups separate
what the code gained from what the lighter defaults gained. Timed in turn, each call finds the other models'
weights in the cache where its own were; "timed alone" is today's gate called repeatedly by itself (its weights
and buffers warm), as a run that only selects experts would call it. Both are printed.

``--averaged K`` adds, for each network gate, a row "NAME x K": the gate of ``ges train-gate --folds K`` (K networks,
their mean probability; ges_core.gating.torch_gate.MeanOfMembers), timed alone as the single gate is.
``--checkpoint LABEL=PATH`` (repeatable) adds a row per trained gate file (``ges train-gate``'s OUT/gate.pt: one
network, K averaged, or K distilled into one with ``--distill``), at its own number of points, timed alone.

The issue's goal: <= 10 ms for CurveNet at 1024 points. The machine's load average is recorded per row:
on a shared machine the wall time includes waiting for a core.

Usage: python benchmarks/gate_speed.py [--repeats 15] [--objects 8] [--baseline REV | --no-baseline] [--label TEXT]
       [--averaged K] [--checkpoint LABEL=PATH ...] [--results NAME]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _gate_baseline import BASELINE_REV, baseline_gate_class  # noqa: E402

from ges_core.gating import GateData, SuccessRates, TrainConfig, fit_cloud, library_clouds  # noqa: E402
from ges_core.objects.library import LibraryConfig, ObjectLibrary  # noqa: E402
from ges_core.registry import load_registry  # noqa: E402

from _results import code_state, results_path, write_results  # noqa: E402

GATES = ("curvenet", "pointnet2", "centroid")
SIZES = (1024, 4096)
EXPERTS = ("small", "medium", "large")


def clouds(n_objects: int) -> tuple[list[str], torch.Tensor, np.ndarray]:
    """Ids, (n, 4096, 3) surface clouds and (n, 3) size-rule success rates of procedural objects."""
    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=1))
    ids = [o.object_id for o in library.list()][:n_objects]
    size = np.array([library.extents(i).max() for i in ids])
    lo, hi = np.quantile(size, [1 / 3, 2 / 3])
    best = np.where(size < lo, 0, np.where(size < hi, 1, 2))
    rates = np.full((len(ids), 3), 0.1)
    rates[np.arange(len(ids)), best] = 0.9
    return ids, library_clouds(library, ids, max(SIZES)), rates


def ready_gate(registry, name: str, n: int, ids, cloud_set: torch.Tensor, rates: np.ndarray):
    """The gate ``name`` reading ``n`` points, ready to predict (seeded weights, or fitted centres)."""
    gate = registry.spec("gate", name).load()(**{**registry.settings("gate", name), "n_points": n})
    if name == "centroid":
        gate.fit(GateData(SuccessRates(ids, EXPERTS, rates), cloud_set), TrainConfig(val_fraction=0.0))
    else:
        torch.manual_seed(0)
        gate.experts, gate.model = EXPERTS, gate.build_model(len(EXPERTS)).eval()
    return gate


def timed(fn, repeats: int) -> tuple[float, float]:
    """Median wall and CPU seconds of ``fn()`` over ``repeats`` calls (after one warm-up call)."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), statistics.median(cpu)


def timed_alternately(fns: dict, repeats: int) -> dict[str, tuple[float, float]]:
    """:func:`timed` of several functions, called in turn (a, b, c, a, b, ...) so that all meet the same load."""
    for fn in fns.values():
        fn()
    samples = {key: ([], []) for key in fns}
    for _ in range(repeats):
        for key, fn in fns.items():
            w, c = time.perf_counter(), time.process_time()
            fn()
            samples[key][0].append(time.perf_counter() - w)
            samples[key][1].append(time.process_time() - c)
    return {key: (statistics.median(w), statistics.median(c)) for key, (w, c) in samples.items()}


def baseline_twin(gate, rev: str, *, same_settings: bool):
    """The gate as the code of git revision ``rev`` builds it, with today's weights and experts: with today's
    settings (``same_settings``: the same function, to check and to time the code alone) or that revision's
    defaults (the gate as it was shipped; k and the walks' length do not change the weights' shapes)."""
    cls = baseline_gate_class(rev, gate.name)
    settings = gate.settings.model_dump() if same_settings else {"n_points": gate.settings.n_points}
    old = cls(**settings)
    old.experts, old.model = gate.experts, old.build_model(len(gate.experts))
    old.model.load_state_dict(gate.model.state_dict())
    old.model.eval()
    return old


def averaged_row(registry, name: str, n: int, k: int, one: torch.Tensor, batch: torch.Tensor, repeats: int) -> dict:
    """The row of ``name``'s gate averaging ``k`` networks (each seeded as :func:`ready_gate`'s), timed alone."""
    members = [ready_gate(registry, name, n, None, None, None) for _ in range(k)]
    return timed_alone(f"{name} x {k}", type(members[0]).averaged(members), n, k, one, batch, repeats)


def timed_alone(label: str, gate, n: int, members: int, one: torch.Tensor, batch: torch.Tensor, repeats: int) -> dict:
    """The row of a ready gate reading ``n`` points, ``members`` networks, timed alone on ``one`` and ``batch``."""
    wall, cpu = timed(lambda: gate.predict(one), repeats)
    wall32, _ = timed(lambda: gate.predict(batch), max(3, repeats // 5))
    print(f"{label} {n:5d} points: {1e3 * wall:7.1f} ms wall, {1e3 * cpu:7.1f} ms CPU", flush=True)
    return {"gate": label, "points": n, "members": members, "ms_per_object": 1e3 * wall, "cpu_ms_per_object":
            1e3 * cpu, "ms_per_object_batch32": 1e3 * wall32 / 32, "load_average": os.getloadavg()[0]}  # fmt: skip


def sized_clouds(ids, big: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """At ``n`` points: (n_objects, n, 3) every object's cloud, (1, n, 3) the first one's and (32, n, 3) a batch
    cycling through the objects."""
    sized = torch.stack([torch.from_numpy(fit_cloud(c.numpy(), n, i)) for c, i in zip(big, ids, strict=True)])
    return sized, sized[:1], sized[torch.arange(32) % len(ids)]


def checkpoint_rows(registry, checkpoints: list[str], ids, big: torch.Tensor, repeats: int) -> list[dict]:
    """A row per ``LABEL=PATH`` (a ``ges train-gate`` checkpoint), at the gate's own number of points."""
    from ges_core.gating import load_gate

    rows = []
    for item in checkpoints:
        label, _, path = item.rpartition("=")
        gate = load_gate(path, registry)
        n = gate.settings.n_points
        _, one, batch = sized_clouds(ids, big, n)
        members = getattr(gate, "members", 1)
        rows.append({**timed_alone(label or path, gate, n, members, one, batch, repeats), "checkpoint": path})
    return rows


def measure(registry, repeats: int, n_objects: int, baseline: str | None, averaged: int = 0,
            checkpoints: list[str] = ()) -> list[dict]:  # fmt: skip
    ids, big, rates = clouds(n_objects)
    rows = checkpoint_rows(registry, list(checkpoints), ids, big, repeats)
    for n in SIZES:
        sized, one, batch = sized_clouds(ids, big, n)
        for name in GATES:
            gate = ready_gate(registry, name, n, ids, sized, rates)
            row = {"gate": name, "points": n}
            if baseline is not None and name != "centroid":
                shipped, same = (baseline_twin(gate, baseline, same_settings=flag) for flag in (False, True))
                with torch.inference_mode():  # logits: the probabilities of untrained weights are ~uniform
                    x = sized / gate.settings.input_scale
                    diff = (same.model(x) - gate.model(x)).abs().max().item()
                fns = {"old": shipped.predict, "old_code": same.predict, "new": gate.predict}
                times = timed_alternately({k: (lambda f=f, x=one: f(x)) for k, f in fns.items()}, repeats)
                wall, cpu = times["new"]
                alone, _ = timed(lambda g=gate, x=one: g.predict(x), repeats)
                row["ms_per_object_alone"] = 1e3 * alone
                row.update({"old_ms_per_object": 1e3 * times["old"][0], "old_cpu_ms_per_object": 1e3 * times["old"][1],
                            "old_code_same_settings_ms_per_object": 1e3 * times["old_code"][0],
                            "old_code_same_settings_cpu_ms_per_object": 1e3 * times["old_code"][1],
                            "speedup": times["old"][0] / wall, "speedup_code_only": times["old_code"][0] / wall,
                            "max_logit_difference_same_settings": diff})  # fmt: skip
            else:
                wall, cpu = timed(lambda g=gate, x=one: g.predict(x), repeats)
            wall32, _ = timed(lambda g=gate, x=batch: g.predict(x), max(3, repeats // 5))
            row.update({"ms_per_object": 1e3 * wall, "cpu_ms_per_object": 1e3 * cpu,
                        "ms_per_object_batch32": 1e3 * wall32 / 32, "load_average": os.getloadavg()[0]})  # fmt: skip
            rows.append(row)
            was = f" (old {row['old_ms_per_object']:.1f} ms, x{row['speedup']:.2f})" if "speedup" in row else ""
            was += f"; alone {row['ms_per_object_alone']:.1f} ms" if "ms_per_object_alone" in row else ""
            print(f"{name:10s} {n:5d} points: {1e3 * wall:7.1f} ms wall, {1e3 * cpu:7.1f} ms CPU{was}", flush=True)
            if averaged > 1 and name != "centroid":
                rows.append(averaged_row(registry, name, n, averaged, one, batch, repeats))
    return rows


def reference_gflops() -> float:
    """Single-thread GFLOP/s of a 512^3 float32 matrix product: how fast this core was during the run."""
    a, b = torch.rand(512, 512), torch.rand(512, 512)
    _, cpu = timed(lambda: a @ b, 9)
    return 2 * 512**3 / cpu / 1e9


def table(rows: list[dict]) -> str:
    lines = [
        "| gate | points | old ms / object | new ms / object | speedup | old CPU ms | new CPU ms "
        "| old code, new settings: ms (speedup) | new ms / object (batch 32) | new ms / object, timed alone "
        "| max logit diff | load avg |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        alone = f"{r['ms_per_object_alone']:.1f}" if "ms_per_object_alone" in r else "-"
        old = (
            (f"{r['old_ms_per_object']:.1f}", f"x{r['speedup']:.2f}", f"{r['old_cpu_ms_per_object']:.1f}",
             f"{r['old_code_same_settings_ms_per_object']:.1f} (x{r['speedup_code_only']:.2f})",
             f"{r['max_logit_difference_same_settings']:.1e}")
            if "speedup" in r else ("-",) * 5
        )  # fmt: skip
        lines.append(
            f"| {r['gate']} | {r['points']} | {old[0]} | {r['ms_per_object']:.1f} | {old[1]} | {old[2]} | "
            f"{r['cpu_ms_per_object']:.1f} | {old[3]} | {r['ms_per_object_batch32']:.1f} | {alone} | {old[4]} | "
            f"{r['load_average']:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--objects", type=int, default=8)
    parser.add_argument("--baseline", default=BASELINE_REV, help="git revision of the old code (default: %(default)s)")
    parser.add_argument("--no-baseline", action="store_true", help="time today's code only")
    parser.add_argument("--label", default="", help="what the machine was doing (recorded with the results)")
    parser.add_argument(
        "--averaged",
        type=int,
        default=0,
        metavar="K",
        help="also time each network gate averaging K networks (ges train-gate --folds K)",
    )
    parser.add_argument("--checkpoint", action="append", default=[], metavar="LABEL=PATH",
                        help="also time this trained gate file (repeatable)")  # fmt: skip
    parser.add_argument("--results", default="gate_speed", metavar="NAME", help="results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, before anything is measured
    baseline = None if args.no_baseline else args.baseline
    torch.set_num_threads(1)
    load_before = os.getloadavg()[0]
    gflops = reference_gflops()
    rows = measure(load_registry(), args.repeats, args.objects, baseline, args.averaged, args.checkpoint)
    print(table(rows))
    print(f"reference: 512^3 matmul at {gflops:.1f} GFLOP/s on one thread; load average {os.getloadavg()[0]:.1f}")
    write_results(
        results,
        {
            "benchmark": "gate_speed",
            "what": "gate.predict time per object, one CPU thread (torch.set_num_threads(1)), median over repeats; "
            "old_*: the gate built by the baseline revision's code with its default settings and today's weights; "
            "old_code_same_settings_*: that code with today's settings (the same function); all timed in turn",
            "goal": "CurveNet at 1024 points <= 10 ms",
            "label": args.label,
            "repeats": args.repeats,
            "baseline": baseline,
            "machine": {
                "cpus": os.cpu_count(),
                "platform": platform.platform(),
                "torch": torch.__version__,
                "load_average_before_after": [load_before, os.getloadavg()[0]],
                "reference_matmul_gflops_one_thread": gflops,
            },
            "code": code_state(),
            "rows": rows,
            "table": table(rows),
        },
    )


if __name__ == "__main__":
    main()
