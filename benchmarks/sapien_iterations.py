"""SAPIEN's solver iterations and the squeeze: what a blocked fingertip presses, and what Stage 1 then validates.

1. The probe: ``ges hand lint --probe``'s cube (``ges_core.lint.checks_probe.probe_tip_forces``: each finger closes
   onto a fixed cube under validation's squeeze targets, which ask 5 N per tip, and its tip force is read after
   0.5 s) for each hand, in SAPIEN at ``--iterations`` (``SceneConfig.solver_iterations``, PhysX TGS position
   iterations; the run default is 20) and in PyBullet at its own setting (100), in one run.
2. ``--datasets NAME=DIR ...`` (optional): finished Stage 1 runs to set side by side, e.g. the real set at the
   default and at ``-o scene.solver_iterations=50``; per run, hand and engine: validated, robust, single-trial and
   robust cross-engine agreement, median seconds of a perturbation trial.

    python benchmarks/sapien_iterations.py [--hands allegro shadow] [--iterations 10 20 50 100] \\
        [--datasets real20=runs/real real50=runs/real_it50 ...] [--results NAME]

Prints both tables; writes ``benchmarks/results/NAME.json`` (default NAME ``sapien_iterations``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow"])
    parser.add_argument("--iterations", nargs="+", type=int, default=[10, 20, 50, 100])
    parser.add_argument("--datasets", nargs="*", default=[], help="NAME=DIR of finished Stage 1 runs")
    parser.add_argument("--results", default="sapien_iterations", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the probes
    import torch

    torch.set_num_threads(1)
    from ges_core.lint.checks_probe import probe_tip_forces
    from ges_core.registry import load_registry

    registry = load_registry()
    probe = {}
    print("| hand | engine | solver iterations | tip force per finger, N (5 N asked) |\n|---|---|---|---|")
    for name in args.hands:
        hand = registry.build_hand(name)
        for iterations in args.iterations:

            def make(sim, config, iterations=iterations):
                return registry.build_sim(sim, config.model_copy(update={"solver_iterations": iterations}))

            forces, _ = probe_tip_forces(hand, make, "sapien")
            probe[f"{name}/sapien/{iterations}"] = forces.round(3).tolist()
            print(f"| {name} | sapien | {iterations} | {_range(forces)} |", flush=True)
        forces, _ = probe_tip_forces(hand, registry.build_sim, "pybullet")
        probe[f"{name}/pybullet/plugin"] = forces.round(3).tolist()
        print(f"| {name} | pybullet | its setting | {_range(forces)} |", flush=True)
    runs = {label: _summary(Path(folder)) for label, folder in (d.split("=", 1) for d in args.datasets)}
    if runs:
        print("\n| run | hand | engine | validated | robust | trial s (median) | agreement single / robust |")
        print("|---|---|---|---|---|---|---|")
        for label, rows in runs.items():
            for row in rows:
                print(f"| {label} | {row['hand']} | {row['simulator']} | {row['validated']}/{row['records']} | "
                      f"{row['robust']}/{row['records']} | {row['trial_s']} | {row['agreement']} |")  # fmt: skip
    write_results(results, {"probe": probe, "runs": runs, "datasets": args.datasets, "code": code_state()})


def _range(forces: np.ndarray) -> str:
    return f"{forces.min():.1f}-{forces.max():.1f} ({', '.join(f'{f:.1f}' for f in forces)})"


def _summary(folder: Path) -> list[dict]:
    from ges_core.dataset import open_dataset
    from ges_core.dataset.summary import agreement, sim_stats

    root = folder / "dataset" if (folder / "dataset" / "manifest.json").exists() else folder
    records = list(open_dataset(root))
    agree = agreement(records)
    out = []
    for s in sim_stats(records):
        a = agree.get(s.hand)
        out.append({
            "hand": s.hand, "simulator": s.simulator, "records": s.records, "validated": s.validated,
            "robust": s.robust, "trial_s": None if s.robust_median is None else round(s.robust_median, 2),
            "agreement": None if a is None else f"{a['single']}/{a['grasps']} / {a['robust']}/{a['robust_grasps']}",
        })  # fmt: skip
    return out


if __name__ == "__main__":
    main()
