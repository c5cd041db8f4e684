"""What the fingertips of Stage 1's kept grasps can hold within the hand's actuators, against the perturbation trials.

For every record of the given datasets with a refined grasp and perturbation trials, the quasi-static fingertip
capacity (``ges_core.synthesis.physics.capacity``: a linear program over the touching fingertips' friction cones,
every joint within its effort limit) at the nominal effective friction and at the friction trial's, as a multiple of
the object's weight. Each drive-limited trial's bound follows: ``limits`` needs 1x at the nominal friction,
``mass_xS`` S x, ``friction_F`` 1x at F. The table sets each trial's bound beside its outcome in every validating
simulator, and counts per hand how many failed trials were beyond the bound (no closing of those fingertips could
pass them), how many failed within it, and how many passed beyond it (contacts the model leaves out: phalanges, the
palm). Pose trials are not bounded (their weight is the nominal's; they fail by geometry) and are left out.

    python benchmarks/stage1_capacity.py --dataset /work/runs/real_s41 runs/demo/dataset [--near 0.01]

Prints the tables and writes ``benchmarks/results/stage1_capacity.json`` (``--results`` another name).
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from pathlib import Path

from ges_core.dataset import open_dataset
from ges_core.env.grasp_source import library_for
from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS
from ges_core.synthesis.physics.capacity import NEAR, fingertip_capacity
from ges_core.synthesis.types import Grasp
from ges_core.threads import set_torch_threads

from _results import code_state, write_results

RESULTS = Path(__file__).parent / "results"
CLOUD_POINTS = 4096
"""Surface samples per object for the touching test and the normals (about 2 mm apart on a 10 cm object)."""
_MASS = re.compile(r"^mass_x([0-9.]+)$")
_FRICTION = re.compile(r"^friction_([0-9.]+)$")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", nargs="+", type=Path, required=True, help="Stage 1 datasets with robust trials")
    parser.add_argument("--near", type=float, default=NEAR, help="a pad this close to the surface touches, m")
    parser.add_argument("--results", default="stage1_capacity", help="name of the JSON under benchmarks/results/")
    args = parser.parse_args()
    set_torch_threads(1)
    registry = load_registry()
    out = {"near": args.near, "datasets": {}, "code": code_state()}
    for folder in args.dataset:
        rows = _rows(folder, registry, args.near)
        counts = _counts(rows)
        out["datasets"][str(folder)] = {"records": rows, "counts": counts}
        print(f"\n{folder}\n" + _table(rows) + "\n\n" + _counts_table(counts))
    path = RESULTS / f"{args.results}.json"
    write_results(path, out)


def _rows(folder: Path, registry, near: float) -> list[dict]:
    dataset = open_dataset(folder)
    config = SynthesisConfig.of_dataset(dataset)
    library = library_for(dataset)
    hands, clouds, rows = {}, {}, []
    for record in sorted(dataset.records(), key=lambda r: (r.hand, r.object_id)):
        trials = {sim: v.trials for sim, v in record.validations.items() if v.trials}
        if record.grasp is None or not trials:
            continue
        if record.hand not in hands:
            hands[record.hand] = registry.build_hand(record.hand)
        if record.object_id not in clouds:
            clouds[record.object_id] = library.point_cloud(record.object_id, CLOUD_POINTS, seed=0)
        asset = library.get(record.object_id)
        nominal = 0.5 * (config.scene.hand_friction + asset.friction)  # the engines average the two coefficients
        grasp = Grasp(record.hand, record.grasp.wrist_pose, record.grasp.q)
        ratio = {}
        for mu in sorted({nominal, *(_friction(t.name, nominal) for ts in trials.values() for t in ts)} - {None}):
            tip = fingertip_capacity(
                hands[record.hand], grasp, *clouds[record.object_id], mu, center=LIBRARY_CENTER_OF_MASS, near=near
            )
            ratio[mu] = tip.ratio(asset.mass)
        fingers = len(tip.fingers)
        outcomes = {}
        for sim, ts in sorted(trials.items()):
            for t in ts:
                need = _need(t.name, nominal)
                if need is not None:
                    scale, mu = need
                    outcomes.setdefault(t.name, {})[sim] = {"passed": t.success, "bound_ok": ratio[mu] >= scale}
        rows.append({
            "hand": record.hand, "object": record.object_id, "mass": asset.mass, "fingers_touching": fingers,
            "ratio_nominal": ratio[nominal], "ratio_by_mu": {f"{mu:g}": r for mu, r in ratio.items()},
            "trials": outcomes,
        })  # fmt: skip
    return rows


def _friction(name: str, nominal: float) -> float | None:
    match = _FRICTION.match(name)
    return min(float(match.group(1)), nominal) if match else None


def _need(name: str, nominal: float) -> tuple[float, float] | None:
    """(weight multiple, friction) a drive-limited trial asks of the fingertips; None for a pose trial."""
    if name == "limits":
        return 1.0, nominal
    if match := _MASS.match(name):
        return float(match.group(1)), nominal
    if (mu := _friction(name, nominal)) is not None:
        return 1.0, mu
    return None


def _counts(rows: list[dict]) -> dict:
    """Per hand: trial outcomes (both simulators) against the bound."""
    out: dict[str, Counter] = {}
    for row in rows:
        tally = out.setdefault(row["hand"], Counter())
        for by_sim in row["trials"].values():
            for o in by_sim.values():
                key = ("passed" if o["passed"] else "failed") + ("_within" if o["bound_ok"] else "_beyond")
                tally[key] += 1
    return {hand: dict(tally) for hand, tally in out.items()}


def _table(rows: list[dict]) -> str:
    trials = sorted({name for row in rows for name in row["trials"]})
    head = "| hand | object | kg | tips | capacity / weight | " + " | ".join(trials) + " |"
    lines = [head, "|" + "---|" * (5 + len(trials))]
    for row in rows:
        caps = ", ".join(f"{r:.2f} at mu {mu}" for mu, r in row["ratio_by_mu"].items())
        cells = []
        for name in trials:
            by_sim = row["trials"].get(name, {})
            mark = " ".join(
                f"{sim[:2]}{'+' if o['passed'] else '-'}{'' if o['bound_ok'] else '!'}" for sim, o in by_sim.items()
            )
            cells.append(mark or "")
        lines.append(
            f"| {row['hand']} | {row['object']} | {row['mass']:.3f} | {row['fingers_touching']} | {caps} | "
            + " | ".join(cells) + " |"
        )  # fmt: skip
    return "\n".join(lines) + "\n(+ held, - failed; ! beyond the fingertips' bound: no closing of them could pass)"


def _counts_table(counts: dict) -> str:
    lines = [
        "| hand | failed, beyond the bound | failed, within it | passed, within it | passed, beyond it |",
        "|---|---|---|---|---|",
    ]
    for hand, c in sorted(counts.items()):
        lines.append(
            f"| {hand} | {c.get('failed_beyond', 0)} | {c.get('failed_within', 0)} | {c.get('passed_within', 0)} | "
            f"{c.get('passed_beyond', 0)} |"
        )
    return "\n".join(lines) + "\n(drive-limited trials in every validating simulator; pose trials left out)"


if __name__ == "__main__":
    main()
