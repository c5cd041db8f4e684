"""Does the order of the wrist placements matter: how often each rank of the fit holds, and what an order by press
alignment or by the fingertips' load bound would meet instead.

Retargeting ranks up to ``attempts`` distinct wrist placements per object by fit (the retargeting objective); the
Stage 1 pipeline tries them in that order until one holds every trial (docs/synthesis/pipeline.md, "Attempts"). This
script takes each of the first ``--placements`` placements through refinement, the nominal validation and the
perturbation trials, in SAPIEN, and scores each by its **press alignment** at its retargeted joints: per finger the
cosine between the direction validation's squeeze pushes its tip (``squeeze.press_directions``: the thumb toward the
other tips, each finger toward the thumb) and the inward normal of the contact it serves (a finger serving two
slots reads its first), the score the lower of the thumb's cosine and the other fingers' mean; and by its **load
margin**: the fingertips' quasi-static capacity at the retargeted joints within the hand's actuator limits
(:func:`ges_core.synthesis.physics.capacity.fingertip_capacity`, the bound ``ges dataset capacity`` reads off a kept
grasp) over what the drive-limited trials ask of it, the lowest over those trials (``trial_asks``: the limits trial
asks the weight at the nominal coefficient, ``mass_xS`` S times it, the friction trial the weight at its coefficient;
1 or more: no trial that changes the load is beyond the bound). Then, per hand, from the same verdicts (nothing is
re-run; a placement's verdict does not depend on when it is tried): the share of placements robust at each rank of
the fit, the objects whose first placement is robust, and how many placements each order tries until the first
robust one (among the objects with one in the first ``--placements``). Orders: ``fit`` (the pipeline's), ``press``
(press alignment, highest first), ``margin`` (load margin, highest first) and ``bound`` (the placements within the
bound first, each group in fit order: the fit's order kept where the bound does not object). Each row also holds the
load margin at the pose refinement reached (``refined_load_margin``; None when refinement gave none): the closing's
own pads, which the retargeted joints only aim at.

Objects: the 20 demo objects, the 20 real scans and ``--library N`` procedural / pybullet_data objects drawn with
``--sample-seed`` (default 40, seed 58). The fallback passes (other strategy, balanced thumb, lower raise) are off:
only the first contacts' placements are measured. One engine (SAPIEN), ``--workers`` processes, one torch thread
each. Measured and discussed: docs/synthesis/retargeting.md, "The order of the placements".

    python benchmarks/placement_order.py [--hands shadow allegro] [--placements 8] [--library 40] [--sample-seed 58]
        [--limit N] [--workers 2] [--results NAME]

Prints a table and writes ``benchmarks/results/NAME.json`` (default ``placement_order``), every placement's row in it,
after each hand (a killed run keeps the hands it finished).
"""

from __future__ import annotations

import argparse
import platform
import random
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ges_core.cli.args import non_negative_int, positive_int
from ges_core.contact import FINGER_SLOTS
from ges_core.dataset import software_versions
from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS
from ges_core.synthesis.physics.capacity import fingertip_capacity
from ges_core.synthesis.physics.squeeze import press_directions, tips_and_jacobians
from ges_core.synthesis.run.capacity import CLOUD_POINTS, trial_asks
from ges_core.synthesis.run.demo import DEMO_OBJECTS

from _results import code_state, results_path, write_results

ROBUST_LEVEL = 3
"""The attempt merit level of a placement robust in the primary simulator (worker._Attempt.merit)."""
ORDERS = ("fit", "press", "margin", "bound")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", nargs="+", default=["shadow", "allegro"])
    parser.add_argument("--placements", type=positive_int, default=8, help="first N placements of the fit order")
    parser.add_argument(
        "--library", type=non_negative_int, default=40, help="library objects drawn besides the demo and real sets"
    )
    parser.add_argument("--sample-seed", type=int, default=58)
    parser.add_argument("--limit", type=positive_int, help="only the first N of those objects (a quick check)")
    parser.add_argument("--workers", type=positive_int, default=2)
    parser.add_argument("--results", default="placement_order", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    ids = object_ids(args.library, args.sample_seed)[: args.limit]
    start = time.perf_counter()
    rows: list[dict] = []
    summary: dict[str, dict] = {}
    for hand in args.hands:
        parts = [ids[w :: args.workers] for w in range(args.workers)]
        with ProcessPoolExecutor(args.workers) as pool:
            for part in pool.map(_probe, [hand] * len(parts), parts, [args.placements] * len(parts)):
                rows += part
        print(f"{hand}: {sum(r['hand'] == hand for r in rows)} placements in {time.perf_counter() - start:.0f} s")
        summary[hand] = summarize([r for r in rows if r["hand"] == hand], args.placements)
        write_results(
            results,
            {
                "benchmark": "placement_order",
                "summary": summary,
                "objects": ids,
                "placements": args.placements,
                "wall_seconds": time.perf_counter() - start,
                "rows": rows,
                "machine": {"platform": platform.platform(), "workers": args.workers},
                "software": software_versions("sapien"),
                "code": code_state(),
            },
        )
    print(table(summary))


def object_ids(library: int, seed: int) -> list[str]:
    """The demo objects, the real scans and ``library`` other procedural / pybullet_data objects (seeded draw)."""
    real = [o.object_id for o in ObjectLibrary(LibraryConfig(sources=("real",))).list()]
    others = [o.object_id for o in ObjectLibrary(LibraryConfig(sources=("procedural", "pybullet"))).list()]
    demo = list(DEMO_OBJECTS)
    pool = [i for i in others if i not in demo]
    return demo + real + random.Random(seed).sample(pool, min(library, len(pool)))


def _probe(hand: str, ids: list[str], placements: int) -> list[dict]:
    """Every one of the first ``placements`` placements of ``hand`` on ``ids`` through refinement, validation and the
    perturbation trials (this process: one torch thread; the pipeline in it with the attempt loop wrapped)."""
    from ges_core.synthesis.run import worker
    from ges_core.threads import set_torch_threads
    from ges_core.transforms import pose_to_matrix

    set_torch_threads(1)
    rows: list[dict] = []
    loop = worker._attempts

    def every_placement(state, sims, hand_name, work, grasps, steps):
        model = state.hand(hand_name)
        normals = np.asarray(work.result.contacts.normals)
        load = LoadMargin(state, hand_name, work)
        for k, grasp in enumerate(grasps[:placements]):
            t0 = time.perf_counter()
            margin = load(grasp)
            margin_seconds = time.perf_counter() - t0
            tried = worker._attempt(state, sims, hand_name, work, grasp)
            if any(tried.pending.values()):
                tried = worker._completed(state, sims, hand_name, work, tried)
            refined = load(tried.refined.grasp) if tried.refined is not None else None
            rotation = pose_to_matrix(grasp.wrist_pose)[:3, :3]  # base frame -> object frame
            press = press_alignment(model, np.asarray(grasp.q), normals @ rotation)
            rows.append(
                {
                    "object": work.object_id,
                    "hand": hand_name,
                    "fit_rank": k,
                    "press_alignment": float(press),
                    "load_margin": margin,
                    "load_margin_seconds": margin_seconds,
                    "refined_load_margin": refined,
                    "refinement": tried.refinement.reason or "ok",
                    "validation": tried.validation.reason or "ok",
                    "robust": tried.robust.reason or "ok",
                    "merit": list(tried.merit),
                }
            )
        sims.reset()
        return loop(state, sims, hand_name, work, grasps[:1], steps)  # the record itself is not measured

    worker._attempts = every_placement
    config = SynthesisConfig(
        library=LibraryConfig(sources=("procedural", "pybullet", "real"), decompose=True),
        attempts=placements,
        other_strategy="never",
        balanced_thumb="never",
        low_raise="never",
    )
    with tempfile.TemporaryDirectory() as out:
        run_synthesis(ids, (hand,), config, Path(out) / "dataset", workers=1, progress=False)
    return rows


class LoadMargin:
    """The load margin (module docs) of one object's placements for one hand: the lowest, over the trials that change
    the load (``trial_asks``, what ``ges dataset capacity`` bounds: limits, mass and friction trials), of the capacity
    at the trial's friction over the weight it asks; inf when the hand declares no effort limits or the run's trials
    are uncapped (no bound), 0 when fewer than two fingertips touch."""

    def __init__(self, state, hand_name: str, work) -> None:
        cfg = state.config(hand_name)
        asset = state.library.get(work.object_id)
        self.hand, self.contacts = state.hand(hand_name), work.result.contacts
        self.cloud = state.library.point_cloud(work.object_id, CLOUD_POINTS, seed=0)
        self.weight = asset.mass * abs(cfg.scene.gravity)
        bounded = cfg.robust.drive_limits and self.hand.description.effort_limits_array is not None
        self.asks = set(trial_asks(cfg, asset, work.seed).values()) if bounded else set()  # (weight multiple, mu)

    def __call__(self, grasp) -> float:
        capacity = {
            mu: fingertip_capacity(
                self.hand, grasp, *self.cloud, mu, center=LIBRARY_CENTER_OF_MASS, contacts=self.contacts
            ).weight
            for mu in {mu for _, mu in self.asks}
        }  # fmt: skip
        return float(min((capacity[mu] / (scale * self.weight) for scale, mu in self.asks), default=float("inf")))


def press_alignment(hand, q: np.ndarray, normals: np.ndarray) -> float:
    """The press alignment (module docs) of joints ``q`` (K,) against contact normals (5, 3): outward, FINGER_SLOTS
    order, the hand's base frame."""
    d = hand.description
    tips, _ = tips_and_jacobians(hand, d.apply_couplings(q))
    push = press_directions(d, tips)  # (F, 3), d.fingers order
    names = [f.name for f in d.fingers]
    first_slot: dict[int, int] = {}
    for s, slot in enumerate(FINGER_SLOTS):
        first_slot.setdefault(names.index(d.finger_for_slot(slot).name), s)
    cos = [float(push[f] @ -normals[first_slot[f]]) for f in range(len(names))]
    thumb = names.index(d.finger_for_slot("thumb").name)
    return min(cos[thumb], statistics.mean(c for f, c in enumerate(cos) if f != thumb))


def summarize(rows: list[dict], placements: int) -> dict:
    """Per rank of the fit, the share of placements robust; per order, what it meets first (module docs)."""
    by_object: dict[str, list[dict]] = {}
    for row in rows:
        by_object.setdefault(row["object"], []).append(row)

    def held(order) -> dict[str, list[bool]]:  # per object, robust or not, in that order
        return {o: [r["merit"][0] >= ROBUST_LEVEL for r in sorted(v, key=order)] for o, v in by_object.items()}

    orders = {
        "fit": held(lambda r: r["fit_rank"]),
        "press": held(lambda r: (-r["press_alignment"], r["fit_rank"])),
        "margin": held(lambda r: (-r["load_margin"], r["fit_rank"])),
        "bound": held(lambda r: (r["load_margin"] < 1.0, r["fit_rank"])),
    }
    robust = orders["fit"]
    by_rank = [[h[k] for h in robust.values() if len(h) > k] for k in range(placements)]
    out = {
        "objects": len(by_object),
        "placements": len(rows),
        "robust_share_by_fit_rank": [round(sum(r) / len(r), 3) if r else None for r in by_rank],
        "robust_share_within_bound": _share([r["merit"][0] >= ROBUST_LEVEL for r in rows if r["load_margin"] >= 1]),
        "robust_share_beyond_bound": _share([r["merit"][0] >= ROBUST_LEVEL for r in rows if r["load_margin"] < 1]),
        "load_margin_seconds_median": statistics.median(r["load_margin_seconds"] for r in rows) if rows else None,
    }
    for name, order in orders.items():
        tries = [h.index(True) + 1 for h in order.values() if any(h)]
        out[name] = {
            "first_robust": sum(h[0] for h in order.values()),
            "with_a_robust_one": len(tries),
            "mean_tried_until_robust": round(statistics.mean(tries), 2) if tries else None,
            "median_tried_until_robust": statistics.median(tries) if tries else None,
        }
    return out


def _share(held: list[bool]) -> dict:
    return {"placements": len(held), "robust": round(sum(held) / len(held), 3) if held else None}


def table(summary: dict) -> str:
    lines = [
        "| hand | objects | robust share at fit rank 1..N | order | first placement robust | objects with one robust "
        "| placements tried until it (mean / median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for hand, s in summary.items():
        shares = " ".join(f"{100 * x:.0f}" for x in s["robust_share_by_fit_rank"] if x is not None)
        for name in ORDERS:
            o = s[name]
            lines.append(
                f"| {hand} | {s['objects']} | {shares} % | {name} | {o['first_robust']} | {o['with_a_robust_one']} "
                f"| {o['mean_tried_until_robust']} / {o['median_tried_until_robust']} |"
            )
    lines += [
        "",
        "| hand | placements within the load bound: robust | beyond it: robust | load margin, s / placement (median) |",
        "|---|---|---|---|",
    ]
    for hand, s in summary.items():
        cells = [s[k] for k in ("robust_share_within_bound", "robust_share_beyond_bound")]
        text = [f"{c['placements']}: {100 * c['robust']:.0f} %" if c["robust"] is not None else "0" for c in cells]
        lines.append(f"| {hand} | {text[0]} | {text[1]} | {s['load_margin_seconds_median']:.4f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
