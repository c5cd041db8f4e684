"""A hand's convex parts per link mesh against its physics and Stage 1: a cap on CoACD's parts per mesh, swept.

For each cap (CoACD's ``max_convex_hull``; "none" = no cap, what ``ges hand prepare`` does), in a process of its own
with the cap put into ``ges_core.hand_prep.decompose.HAND_COACD``: the decomposition of every deep-hulled link mesh
(parts, CoACD seconds), ``ges sim check``'s close-and-lift of a box in SAPIEN and PyBullet with the hand's settings
(its verdict, or the blow-up that stopped it: a merged part can bulge far beyond the mesh it stands for), the engines'
raw step time with the hand closed on a box (``benchmarks/sim_throughput.py``'s scene; none where it blew up),
then Stage 1 on procedural objects and real scans as ``benchmarks/stage1_speed.py`` times it (one process, one torch
thread, CPU clock, SAPIEN, the single nominal trial: robust trials off), with each record's physics steps. The caps
run in turn, round after round (``--rounds``), so that all meet the same machine load. The table has a row per cap
(medians over the rounds, how many objects were validated), then the ratios to the first cap given, the objects whose
verdict changed, each cap's sim checks and its parts per mesh.

    python benchmarks/hand_parts.py [--hand inspire] [--caps none 32 16 8] [--procedural 12] [--real 10] [--rounds 2]
        [--results hand_parts]

The hand's package must be installed (``pip install -e examples/ges-inspire-hand``). A cap's first round decomposes
its meshes (minutes for the Inspire; cached after). Results: ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402

STEP_KEYS = ("contacts", "retargeting", "refinement", "validation", "total", "setup", "physics_steps")
SIMS = ("sapien", "pybullet")


def child(cap: int, hand: str, procedural: int, real: int, out: Path) -> None:
    """One cap's decomposition and Stage 1 run (this process only), written to ``out`` as JSON."""
    import ges_core.hand_prep.decompose as decompose

    decompose.HAND_COACD = replace(decompose.HAND_COACD, max_convex_hull=cap)  # read at call time by the lookups
    from sim_throughput import bench_pair
    from stage1_speed import first_object, object_sets, per_record, run_pipeline, steps_per_record, summarize, warm_up

    from ges_core.config import parse_model
    from ges_core.errors import SimulationError
    from ges_core.hand_prep.prepare import prepare_hand
    from ges_core.hand_settings import hand_sim_check_config
    from ges_core.objects.library import LibraryConfig
    from ges_core.registry import load_registry
    from ges_core.sim_check import SimCheckConfig, build_check_object, run_sim_check
    from ges_core.synthesis import SynthesisConfig
    from ges_core.threads import set_torch_threads

    set_torch_threads(1)
    registry = load_registry()
    model = registry.build_hand(hand)
    report = prepare_hand(model, progress=False)
    meshes = [
        {"mesh": m.path.name, "links": m.links, "hull_gap": m.hull_gap, "parts": m.parts, "coacd_seconds": m.seconds}
        for m in report.meshes
    ]
    check, raw = {}, {}
    check_config = hand_sim_check_config(model.description, SimCheckConfig())  # as `ges sim check --hand H`
    for sim in SIMS:
        try:
            with registry.build_sim(sim, check_config.scene) as backend:
                got = run_sim_check(model, backend, check_config, build_check_object(check_config))
            check[sim] = f"{'OK' if got.ok else 'FAILED'}: {got.touching} tips, box up {got.object_rise * 1000:.0f} mm"
        except SimulationError as error:
            check[sim] = f"blew up: {str(error)[:90]}"
        try:
            raw[sim] = bench_pair(registry, hand, sim, steps=300, repeats=3)["raw_us_per_step"]
        except SimulationError:
            raw[sim] = None
    library_config = LibraryConfig(sources=("procedural", "pybullet", "real"))
    library = library_config.build()
    sets = object_sets(library, procedural, real)
    _, no_collision = warm_up(library, [i for ids in sets.values() for i in ids])
    config = parse_model(SynthesisConfig, {"library": library_config.model_dump(), "robust": {"enabled": False}})
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        run_pipeline([first_object(sets)], [hand], config, Path(tmp) / "warm", "wall")  # imports: untimed
        for group, ids in sets.items():
            with steps_per_record() as counts:
                got, wall = run_pipeline(ids, [hand], config, Path(tmp) / group, "cpu")
            rows = [per_record(r, counts) for r in got]
            runs[group] = {
                "summary": summarize(rows, set(no_collision)),
                "cpu_per_record": wall["cpu"] / len(got),
                "verdicts": {r["object"]: r["failed_step"] or "validated" for r in rows},
            }
    out.write_text(json.dumps({"cap": cap, "meshes": meshes, "sim_check": check, "raw_us_per_step": raw, "sets": runs}))


def run_child(cap: int, args, folder: Path) -> dict:
    out = folder / f"cap{cap}.json"
    command = [sys.executable, __file__, "--child", str(cap), "--hand", args.hand]
    command += ["--procedural", str(args.procedural), "--real", str(args.real), "--child-out", str(out)]
    subprocess.run(command, check=True)
    return json.loads(out.read_text())


def _us(value: float | None) -> str:
    return "blew up" if value is None else f"{value:.0f}"


def _ratio(value: float | None, base: float | None) -> str:
    return "-" if value is None or base is None else f"{value / base:.2f}"


def _cap(text: str) -> int:
    return -1 if text == "none" else int(text)


def _label(cap: int) -> str:
    return "none" if cap < 0 else str(cap)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--hand", default="inspire")
    p.add_argument("--caps", nargs="+", type=_cap, default=[-1, 32, 16, 8], help="part caps ('none': no cap)")
    p.add_argument("--procedural", type=int, default=12, help="procedural categories (object 000)")
    p.add_argument("--real", type=int, default=10, help="real scans (the first N)")
    p.add_argument("--rounds", type=int, default=2, help="runs of every cap, in turn")
    p.add_argument("--results", default="hand_parts")
    p.add_argument("--child", type=int, help=argparse.SUPPRESS)
    p.add_argument("--child-out", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child is not None:
        child(args.child, args.hand, args.procedural, args.real, args.child_out)
        return
    results = results_path(args.results)
    runs: dict[int, list[dict]] = {cap: [] for cap in args.caps}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for cap in args.caps:
                print(f"round {r + 1} of {args.rounds}: cap {_label(cap)}", flush=True)
                runs[cap].append(run_child(cap, args, Path(tmp)))
    rows = []
    for cap, got in runs.items():
        meshes = got[0]["meshes"]
        row = {"cap": _label(cap), "shapes": sum(max(m["parts"], 1) * len(m["links"]) for m in meshes)}
        for sim in SIMS:
            times = [g["raw_us_per_step"][sim] for g in got if g["raw_us_per_step"][sim] is not None]
            row[f"{sim}_us_per_step"] = statistics.median(times) if times else None
            row[f"{sim}_sim_check"] = got[0]["sim_check"][sim]
        for group in got[0]["sets"]:
            for key in STEP_KEYS:
                values = [g["sets"][group]["summary"][key] for g in got]
                row[f"{group}.{key}"] = statistics.median(v for v in values if v is not None)
            row[f"{group}.cpu_per_record"] = statistics.median(g["sets"][group]["cpu_per_record"] for g in got)
            verdicts = got[0]["sets"][group]["verdicts"]
            row[f"{group}.validated"] = sum(v == "validated" for v in verdicts.values())
            row[f"{group}.objects"] = len(verdicts)
        rows.append(row)
    groups = list(runs[args.caps[0]][0]["sets"])
    print(f"\nhand '{args.hand}': Stage 1 per object, medians over {args.rounds} round(s), CPU seconds on one core:")
    head = "| cap | shapes | SAPIEN / PyBullet us per step | " + " | ".join(
        f"{g}: refinement | validation | total | CPU s per record | physics steps | validated" for g in groups
    )
    print(head + " |")
    print("|" + "---|" * (3 + 6 * len(groups)))
    for row in rows:
        cells = [row["cap"], str(row["shapes"])]
        cells.append(" / ".join(_us(row[f"{sim}_us_per_step"]) for sim in SIMS))
        for g in groups:
            cells += [f"{row[f'{g}.{k}']:.3f}" for k in ("refinement", "validation", "total", "cpu_per_record")]
            cells += [f"{row[f'{g}.physics_steps']:.0f}", f"{row[f'{g}.validated']}/{row[f'{g}.objects']}"]
        print("| " + " | ".join(cells) + " |")
    base = rows[0]
    print(f"\nratio to cap {base['cap']} (raw step SAPIEN, PyBullet; per set: total, CPU s per record):")
    for row in rows[1:]:
        print(
            f"  cap {row['cap']}: "
            + ", ".join(f"{sim} {_ratio(row[f'{sim}_us_per_step'], base[f'{sim}_us_per_step'])}" for sim in SIMS)
            + "; "
            + ", ".join(
                f"{g} {row[f'{g}.total'] / base[f'{g}.total']:.2f} / "
                f"{row[f'{g}.cpu_per_record'] / base[f'{g}.cpu_per_record']:.2f}"
                for g in groups
            )
        )
    changed = {}
    first = runs[args.caps[0]][0]["sets"]
    for cap in args.caps[1:]:
        other = runs[cap][0]["sets"]
        diff = {
            o: f"{first[g]['verdicts'][o]} -> {other[g]['verdicts'][o]}"
            for g in groups
            for o in first[g]["verdicts"]
            if first[g]["verdicts"][o] != other[g]["verdicts"].get(o)
        }
        changed[_label(cap)] = diff
        print(f"verdicts changed, cap {_label(args.caps[0])} -> {_label(cap)}: {diff or 'none'}")
    print("\n`ges sim check` (the hand's settings), SAPIEN | PyBullet:")
    for row in rows:
        print(f"  cap {row['cap']}: " + " | ".join(row[f"{sim}_sim_check"] for sim in SIMS))
    print("\nparts per link mesh:")
    for cap, got in runs.items():
        print(
            f"  cap {_label(cap)}: "
            + ", ".join(f"{m['mesh'][:20]} {m['parts']}" for m in got[0]["meshes"] if m["parts"])
        )
    write_results(
        results,
        {
            "hand": args.hand,
            "rounds": args.rounds,
            "rows": rows,
            "verdicts_changed": changed,
            "runs": {_label(c): g for c, g in runs.items()},
            "code": code_state(),
        },
    )


if __name__ == "__main__":
    main()
