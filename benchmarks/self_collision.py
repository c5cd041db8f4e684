"""Which hand-hand pairs collide: the Shadow hand with its MJCF's pair list against every pair but the neighbours.

The Shadow's MJCF (gymnasium-robotics) lets 18 link pairs collide and turns every other hand-hand pair off; a hand
given as a URDF collides every pair but the neighbours (188 here). ``settings.hand.shadow.self_collision`` picks
``mjcf_pairs`` (the default since 5 December 2026) or ``all`` (docs/hands/shadow.md, "Self-collision"). Both are
run side by side in one process (one torch thread, CPU time):

* **physics step**: the hand alone, base fixed, no gravity, at 24 seeded random joint poses within the limits;
  the best of 3 blocks of 50 raw engine steps per pose (thread CPU time), median over the poses; SAPIEN also
  counts the shape pairs PhysX reports at each pose (hand-hand and hand-table: the base sits at the table's height,
  so some poses put fingers into it; the same poses for both settings).
* **Stage 1**: ``run_synthesis`` on the procedural shapes (object 000 of each category, as
  ``benchmarks/stage1_speed.py``), the demo objects and the real scans, SAPIEN refining and validating, robust
  trials on (the defaults), the objects in chunks of 5 with the two settings alternating chunk by chunk (which
  goes first alternates too), so a drifting machine loads both alike. Per set: validated, robust, the median of
  contacts + retargeting + refinement + validation per object (the issue's "total", CPU seconds), and the
  median placements tried.

    python benchmarks/self_collision.py [--procedural 28] [--demo 20] [--real 20] [--poses 24] [--results NAME]

Prints markdown tables and writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from stage1_speed import per_record, run_pipeline

from ges_core.objects.library import LibraryConfig
from ges_core.objects.procedural import CATEGORIES
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.run.demo import DEMO_OBJECTS
from ges_core.synthesis.run.tasks import RegistrySpec
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results

SETTINGS = ("mjcf_pairs", "all")
CHUNK = 5


def _override(setting: str) -> str:
    return f"settings.hand.shadow.self_collision={setting}"


def step_costs(poses: int, blocks: int = 3, steps: int = 50) -> dict:
    """Per simulator and setting: median µs per raw engine step over random poses (and SAPIEN's shape pairs)."""
    out: dict = {}
    hands = {s: load_registry(overrides=(_override(s),)).build_hand("shadow") for s in SETTINGS}
    d = hands[SETTINGS[0]].description
    lim = d.limits_array
    rng = np.random.default_rng(0)
    qs = [d.apply_couplings(rng.uniform(lim[:, 0], lim[:, 1])) for _ in range(poses)]
    registry = load_registry()
    for sim_name in ("sapien", "pybullet"):
        sims = {s: registry.build_sim(sim_name, SceneConfig(self_collision=True, gravity=0.0)) for s in SETTINGS}
        times = {s: [] for s in SETTINGS}
        pairs = {s: [] for s in SETTINGS}
        try:
            for s, sim in sims.items():
                sim.load_hand(hands[s], floating=False)
            for i, q in enumerate(qs):
                order = SETTINGS if i % 2 == 0 else SETTINGS[::-1]
                best = dict.fromkeys(SETTINGS, np.inf)
                for _ in range(blocks):
                    for s in order:
                        sim = sims[s]
                        sim.set_hand_state(q[None])
                        sim.set_joint_targets(q[None])
                        sim.engine_step()
                        start = time.thread_time()
                        for _ in range(steps):
                            sim.engine_step()
                        best[s] = min(best[s], (time.thread_time() - start) / steps * 1e6)
                for s in SETTINGS:
                    times[s].append(best[s])
                    if sim_name == "sapien":
                        pairs[s].append(len(sims[s]._envs[0].scene.get_contacts()))
        finally:
            for sim in sims.values():
                sim.close()
        out[sim_name] = {
            s: {
                "step_us_median": statistics.median(times[s]),
                "shape_pairs_median": statistics.median(pairs[s]) if pairs[s] else None,
            }
            for s in SETTINGS
        }
    return out


def stage1(sets: dict[str, list[str]], folder: Path) -> dict:
    """Per set and setting: the records' validated / robust counts and median step seconds (CPU)."""
    rows: dict = {name: {s: [] for s in SETTINGS} for name in sets}
    config = SynthesisConfig(library=LibraryConfig(sources=("procedural", "pybullet", "real")))
    turn = 0
    for name, ids in sets.items():
        for at in range(0, len(ids), CHUNK):
            chunk = ids[at : at + CHUNK]
            for s in SETTINGS if turn % 2 == 0 else SETTINGS[::-1]:
                out = folder / f"{name}-{s}"
                spec = RegistrySpec(overrides=(_override(s),))
                records, _ = run_pipeline(chunk, ["shadow"], config, out, "cpu", registry=spec)
                rows[name][s] = [per_record(r) | {"robust_ok": r.robust, "validated": _validated(r)} for r in records]
            turn += 1
    return {name: {s: _summary(rows[name][s]) for s in SETTINGS} for name in sets}


def _validated(record) -> bool:
    verdict = record.validations.get("sapien")
    return bool(verdict and verdict.success)


def _summary(rows: list[dict]) -> dict:
    totals = [sum(v or 0.0 for v in r["steps"].values()) for r in rows if r["steps"]["refinement"] is not None]
    return {
        "records": len(rows),
        "validated": sum(r["validated"] for r in rows),
        "robust": sum(bool(r["robust_ok"]) for r in rows),
        "total_s_median": statistics.median(totals) if totals else None,
        "refinement_s_median": statistics.median(r["steps"]["refinement"] or 0.0 for r in rows),
        "validation_s_median": statistics.median(r["steps"]["validation"] or 0.0 for r in rows),
        "robust_s_median": statistics.median(r["robust"] or 0.0 for r in rows),
        "attempts_median": statistics.median(r["attempts"] for r in rows),
        "failures": sorted(f"{r['object']}: {r['failed_step']} {r['failure']}" for r in rows if r["failed_step"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedural", type=int, default=len(CATEGORIES), help="object 000 of the first N categories")
    parser.add_argument("--demo", type=int, default=len(DEMO_OBJECTS), help="first N demo objects")
    parser.add_argument("--real", type=int, default=20, help="first N real scans")
    parser.add_argument("--poses", type=int, default=24, help="random joint poses of the step timing")
    parser.add_argument("--results", default="self_collision_shadow", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    path = results_path(args.results)
    set_torch_threads(1)
    real = [e.object_id for e in LibraryConfig(sources=("real",)).build().entries(source="real")][: args.real]
    procedural = [f"procedural/{c}/000" for c in list(CATEGORIES)[: args.procedural]]
    sets = {"procedural": procedural, "demo": list(DEMO_OBJECTS[: args.demo]), "real": real}
    sets = {name: ids for name, ids in sets.items() if ids}  # --real 0 etc.: the set is left out
    steps = step_costs(args.poses)
    print("| simulator | setting | raw step, µs (median of poses) | shape pairs (SAPIEN) |\n|---|---|---|---|")
    for sim_name, by in steps.items():
        for s, v in by.items():
            print(f"| {sim_name} | {s} | {v['step_us_median']:.1f} | {v['shape_pairs_median'] or '-'} |")
    with tempfile.TemporaryDirectory() as tmp:
        runs = stage1(sets, Path(tmp))
    print("\n| set | setting | validated | robust | total s (median) | refinement | validation | robust trials s "
          "| placements |\n|---|---|---|---|---|---|---|---|---|")  # fmt: skip
    for name, by in runs.items():
        for s, v in by.items():
            print(f"| {name} | {s} | {v['validated']}/{v['records']} | {v['robust']}/{v['records']} | "
                  f"{v['total_s_median']:.3f} | {v['refinement_s_median']:.3f} | {v['validation_s_median']:.3f} | "
                  f"{v['robust_s_median']:.3f} | {v['attempts_median']} |")  # fmt: skip
    write_results(path, {"code": code_state(), "step": steps, "stage1": runs, "sets": sets})


if __name__ == "__main__":
    main()
