"""The wrist search's collision points per link, capped (MAX_LINK_POINTS, farthest-point spread) or every part's:
retargeting time and the grasps chosen, side by side in one run.

A link whose mesh ``ges hand prepare`` decomposed has one ``<collision>`` per convex part, and each part gave up to
24 points (its hull vertices): the prepared Inspire hand had 13,383 points (the Allegro 248) and its retargeting
took 2.8 s per object. The cap keeps at most ``MAX_LINK_POINTS`` per link (``ges_core.collision_points``).

For each hand: contacts of the 20 demo objects (``DEMO_OBJECTS``, the run's contact settings for that hand, each
object's seed), then ``GraspRetargeter.retarget_ranked`` over all of them as one batch (what one worker chunk does)
with the capped points and with every part's points, alternating ``--rounds`` times; one torch thread. Reported:
points, median seconds per object, the ratio, and how many objects get the same best placement (wrist pose within
1 mm / 1 degree, joints within 0.01 rad) and the same reached verdict. Hands not installed are skipped.

    python benchmarks/hand_points.py [--hands allegro shadow ability inspire] [--rounds 3] [--results NAME]

Writes benchmarks/results/NAME.json (default NAME hand_points).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", nargs="+", default=["allegro", "shadow", "ability", "inspire"])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--results", default="hand_points", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the rounds
    torch.set_num_threads(1)
    from ges_core.errors import UnknownNameError
    from ges_core.registry import load_registry

    registry = load_registry()
    rows = []
    for name in args.hands:
        try:
            hand = registry.build_hand(name)
        except UnknownNameError:
            print(f"{name}: not installed, skipped")
            continue
        rows.append(_row(hand, args.rounds))
        r = rows[-1]
        print(f"{name}: points {r['points_capped']} / {r['points_all']}, s per object {r['capped_s']:.3f} / "
              f"{r['all_s']:.3f} (x{r['ratio']:.2f}), same best placement {r['same_best']}/{r['objects']}, "
              f"same reached {r['same_reached']}/{r['objects']}", flush=True)  # fmt: skip
    print("\n| hand | points capped / all | s per object capped / all | ratio | same best placement | same reached |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['hand']} | {r['points_capped']} / {r['points_all']} | {r['capped_s']:.3f} / {r['all_s']:.3f} | "
              f"{r['ratio']:.2f} | {r['same_best']}/{r['objects']} | {r['same_reached']}/{r['objects']} |")  # fmt: skip
    write_results(results, {"rounds": args.rounds, "rows": rows, "code": code_state()})


def _row(hand, rounds: int) -> dict:
    from unittest import mock

    import ges_core.collision_points as points_module
    from ges_core.collision_points import collision_points
    from ges_core.errors import SynthesisError
    from ges_core.synthesis import SynthesisConfig
    from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS, generate_contacts
    from ges_core.synthesis.physics import table_clearance
    from ges_core.synthesis.retarget.retargeter import GraspRetargeter
    from ges_core.synthesis.retarget.search import ObjectCloud
    from ges_core.synthesis.run.demo import DEMO_OBJECTS
    from ges_core.synthesis.run.tasks import object_seed

    base = SynthesisConfig()
    cfg = base.for_hand(hand.name, hand.description.settings)
    library = base.library.build()
    contacts, clouds = [], []
    for object_id in DEMO_OBJECTS:
        seed = object_seed(base.seed, object_id)
        points, normals = library.point_cloud(object_id, base.points, seed=seed)
        try:
            result = generate_contacts(
                points, normals, cfg.contacts, object_id=object_id, seed=seed, center_of_mass=LIBRARY_CENTER_OF_MASS
            )
        except SynthesisError:
            continue
        contacts.append(result.contacts)
        clouds.append(ObjectCloud(points, normals))
    every_part = lambda text: collision_points(text, max_link_points=10**9)  # noqa: E731
    solvers = {"capped": GraspRetargeter(hand, cfg.retarget, thumb_keep=cfg.thumb_keep)}
    # the points come from table_clearance.finger_points (cached per URDF), which imports collision_points when
    # it builds them: the uncapped solver gets a fresh build with the patched function, and the cache is cleared
    # again so that nothing after it reads every part's points
    table_clearance._finger_points.cache_clear()
    with mock.patch.object(points_module, "collision_points", every_part):
        solvers["all"] = GraspRetargeter(hand, cfg.retarget, thumb_keep=cfg.thumb_keep)
    table_clearance._finger_points.cache_clear()
    seconds: dict[str, list[float]] = {"capped": [], "all": []}
    best = {}
    for _ in range(rounds):
        for mode, solver in solvers.items():
            start = time.perf_counter()
            ranked = solver.retarget_ranked(contacts, clouds, keep=cfg.attempts)
            seconds[mode].append((time.perf_counter() - start) / len(contacts))
            best[mode] = [r if isinstance(r, SynthesisError) else r[0] for r in ranked]
    same_best = same_reached = 0
    for a, b in zip(best["capped"], best["all"], strict=True):
        if isinstance(a, SynthesisError) or isinstance(b, SynthesisError):
            same_best += isinstance(a, SynthesisError) and isinstance(b, SynthesisError)
            same_reached += isinstance(a, SynthesisError) and isinstance(b, SynthesisError)
            continue
        same_reached += bool(a.meta.get("reached", True)) == bool(b.meta.get("reached", True))
        dq = float(np.abs(np.asarray(a.q) - np.asarray(b.q)).max())
        dp = float(np.linalg.norm(np.asarray(a.wrist_pose[:3]) - np.asarray(b.wrist_pose[:3])))
        dot = abs(float(np.dot(a.wrist_pose[3:], b.wrist_pose[3:])))
        angle = float(np.degrees(2 * np.arccos(min(1.0, dot))))
        same_best += dp < 1e-3 and angle < 1.0 and dq < 0.01
    capped, every = statistics.median(seconds["capped"]), statistics.median(seconds["all"])
    return {
        "hand": hand.name, "objects": len(contacts),
        "points_capped": len(solvers["capped"].hull.points), "points_all": len(solvers["all"].hull.points),
        "capped_s": capped, "all_s": every, "ratio": capped / every, "seconds": seconds,
        "same_best": int(same_best), "same_reached": int(same_reached),
    }  # fmt: skip


if __name__ == "__main__":
    main()
