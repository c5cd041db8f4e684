"""The two forms of the observation's wrist rotation side by side: what each costs per control step, and what
recasting costs an expert made for the other form.

For 1, 8 and 32 envs (the Allegro over the box of ``benchmarks/env_throughput.py``, after its full reset, in
SAPIEN; one process, one torch thread), two ``GraspEnv`` s that differ only in ``EnvConfig.wrist_rotation``
('matrix', the default; 'rotvec', the form before 8 December 2026) are timed in turn, ``--repeats`` rounds of
``--calls`` calls each, medians per call:

* observe: ``GraspEnv.observe()`` (the backend's reads and the observation maths; the rest of a step is the same
  in both forms);
* recast: ``ObservationLayout.recast`` of the matrix env's observations to the rotation vector (what
  ``RecastWrist`` adds to every ``act`` of a checkpoint trained before the matrix form) and back.

    python benchmarks/wrist_observation.py [--envs 1 8 32] [--calls 200] [--repeats 5] [--results NAME]

Writes ``benchmarks/results/NAME.json`` (default ``wrist_observation``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from env_throughput import build  # noqa: E402

from ges_core.env.grasp_env import EnvConfig  # noqa: E402
from ges_core.registry import load_registry  # noqa: E402

from _results import code_state, results_path, write_results  # noqa: E402

FORMS = ("matrix", "rotvec")


def per_call_us(fn, calls: int) -> float:
    """Microseconds per call of ``fn`` over ``calls`` calls."""
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return 1e6 * (time.perf_counter() - start) / calls


def measure(n: int, calls: int, repeats: int) -> dict:
    """One row: observe per form and recast both ways, medians over ``repeats`` interleaved rounds, n envs."""
    registry = load_registry()
    envs = {form: build(registry, "sapien", "allegro", n, EnvConfig(wrist_rotation=form))[0].env for form in FORMS}
    try:
        matrix, rotvec = (envs[f].obs_layout for f in FORMS)
        obs, _ = envs["matrix"].observe()
        back = matrix.recast(obs, rotvec)
        fns = {
            "observe_matrix_us": envs["matrix"].observe,
            "observe_rotvec_us": envs["rotvec"].observe,
            "recast_to_rotvec_us": lambda: matrix.recast(obs, rotvec),
            "recast_to_matrix_us": lambda: rotvec.recast(back, matrix),
        }
        samples = {key: [] for key in fns}
        for _ in range(repeats):
            for key, fn in fns.items():
                samples[key].append(per_call_us(fn, calls))
    finally:
        for env in envs.values():
            env.sim.close()
    row = {"envs": n, **{key: statistics.median(v) for key, v in samples.items()}}
    row["observe_ratio_matrix_to_rotvec"] = row["observe_matrix_us"] / row["observe_rotvec_us"]
    row["load_average"] = os.getloadavg()[0]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", type=int, default=[1, 8, 32])
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--results", default="wrist_observation", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    out = results_path(args.results)
    torch.set_num_threads(1)
    print(
        "| envs | observe, matrix (us) | observe, rotvec (us) | ratio | recast to rotvec (us) | recast to matrix (us) |"
    )
    print("|---|---|---|---|---|---|")
    rows = []
    for n in args.envs:
        r = measure(n, args.calls, args.repeats)
        rows.append(r)
        print(f"| {n} | {r['observe_matrix_us']:.1f} | {r['observe_rotvec_us']:.1f} | "
              f"x {r['observe_ratio_matrix_to_rotvec']:.3f} | {r['recast_to_rotvec_us']:.1f} | "
              f"{r['recast_to_matrix_us']:.1f} |", flush=True)  # fmt: skip
    write_results(out, {"benchmark": "wrist_observation", "calls": args.calls, "repeats": args.repeats,
                        "code": code_state(), "rows": rows})  # fmt: skip


if __name__ == "__main__":
    main()
