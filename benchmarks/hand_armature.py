"""A hand's joint armature and what a blocked fingertip presses, per engine: the figures of docs/hands/shadow.md.

For each hand and armature variant, in each simulator, two probes of validation's squeeze (5 N asked per tip):

* **all fingers**: ``ges hand lint --probe``'s probe (``ges_core.lint.checks_probe.probe_fingers``): one scene
  per finger, every finger closing under the squeeze targets, finger ``f``'s tip force on its fixed cube;
* **one finger**: the same cubes, but in scene ``f`` only finger ``f`` gets its squeeze targets (the others stay at
  the probe's start pose, so no neighbour touches the cube; ``probe_fingers(..., alone=True)``), its tip force and
  the largest joint speed of the hand after the 60 squeeze steps (a blocked finger that chatters moves; a still one
  does not).

Variants: ``declared`` (the hand as built), ``none`` (``armature`` left out), and each ``--try LABEL=KG_M2`` (that
armature on every joint, e.g. ``hora=0.001``, the Allegro's in HORA's Isaac Gym task). PyBullet has no joint
armature: its rows show that the variants do not change it.

    python benchmarks/hand_armature.py [--hands shadow allegro] [--sims sapien pybullet] [--try hora=0.001]
        [--results NAME]

Prints a markdown table and writes ``benchmarks/results/NAME.json`` (default ``hand_armature``).
"""

from __future__ import annotations

import argparse

from ges_core.cli.args import positive_float

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", nargs="+", default=["shadow", "allegro"])
    parser.add_argument("--sims", nargs="+", default=["sapien", "pybullet"])
    parser.add_argument("--try", dest="tries", action="append", default=[], metavar="LABEL=KG_M2",
                        help="a variant with this armature on every joint (repeatable)")  # fmt: skip
    parser.add_argument("--results", default="hand_armature", help="results name (benchmarks/results/NAME.json)")
    args = parser.parse_args()
    out_path = results_path(args.results)
    tries = [_variant(text) for text in args.tries]
    import torch

    torch.set_num_threads(1)
    from ges_core.registry import load_registry

    registry = load_registry()
    rows = []
    print("| hand | armature | engine | all fingers: tip N | one finger: tip N | one finger: top joint speed, rad/s |")
    print("|---|---|---|---|---|---|")
    for name in args.hands:
        variants = [("declared", {}), ("none", {"armature": None}), *((lbl, {"armature": v}) for lbl, v in tries)]
        for label, override in variants:
            hand = registry.spec("hand", name).load()(**{**registry.settings("hand", name), **override})
            for sim in args.sims:
                row = {"hand": name, "armature": label, "values": sorted(set(hand.description.armature)), "sim": sim}
                row |= _probes(hand, registry, sim)
                rows.append(row)
                print(f"| {name} | {label} {row['values'] or ''} | {sim} | {_fmt(row['all_fingers'])} | "
                      f"{_fmt(row['one_finger'])} | {row['one_finger_speed']:.2f} |", flush=True)  # fmt: skip
    write_results(out_path, {"benchmark": "hand_armature", "asked_n": 5.0, "rows": rows, "code": code_state()})


def _variant(text: str) -> tuple[str, float]:
    label, _, value = text.partition("=")
    if not label or not value:
        raise SystemExit(f"--try takes LABEL=KG_M2, e.g. hora=0.001; got {text!r}")
    try:
        return label, positive_float(value)
    except argparse.ArgumentTypeError as exc:
        raise SystemExit(f"--try {text!r}: {exc}") from None


def _probes(hand, registry, sim: str) -> dict:
    from ges_core.lint.checks_probe import probe_fingers

    every = probe_fingers(hand, registry.build_sim, sim)
    one = probe_fingers(hand, registry.build_sim, sim, alone=True)
    return {
        "all_fingers": every.forces.round(3).tolist(),
        "one_finger": one.forces.round(3).tolist(),
        "one_finger_speed": one.joint_speed,
    }


def _fmt(values: list[float]) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


if __name__ == "__main__":
    main()
