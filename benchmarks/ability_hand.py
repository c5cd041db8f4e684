"""The Ability hand package (examples/ges-ability-hand) on the 20 demo objects, both engines, and from contacts
retargeted off an Allegro and a Shadow dataset of the same objects: each step's success, validated (single
trial) and robust counts per simulator. Results: ``benchmarks/results/NAME.json`` (``--results NAME``, default
``ability_hand``).

Runs the commands of docs/tutorials/new-hand.md (``ges hand prepare ability`` first, so the decomposed
palm and phalanx are used), single process::

    python benchmarks/ability_hand.py --work /tmp/ability_bench [--results NAME]   # ~10 min on 2 loaded cores
    python benchmarks/ability_hand.py --work /tmp/ability_bench --summarize-only [--results NAME]   # re-read

Needs the package installed (``pip install -e examples/ges-ability-hand``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ges_core.synthesis.run.demo import DEMO_OBJECTS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402

SIMS = ("sapien", "pybullet")
STEPS = ("contacts", "retargeting", "refinement")


def ges(*args: str) -> float:
    """Run ``ges ARGS`` (checked); seconds it took."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ges_core.cli", *args], check=True)
    return time.perf_counter() - start


def summarize(root: Path, hand: str) -> dict:
    """Per step ok/attempted, and per simulator validated/robust counts of ``hand``'s records in ``root``."""
    records = []
    for path in sorted((root / "records" / hand).glob("*.npz")):
        with np.load(path) as z:
            records.append(json.loads(str(z["record_json"])))
    out: dict = {"objects": len(records), "steps": {}, "sims": {}}
    for step in STEPS:
        tried = [r for r in records if r["steps"][step]["reason"] != "skipped"]
        out["steps"][step] = [sum(r["steps"][step]["ok"] for r in tried), len(tried)]
    for sim in SIMS:
        runs = [r["validations"].get(sim) for r in records]
        out["sims"][sim] = {
            "validated": sum(bool(v and v["success"]) for v in runs),
            "robust": sum(
                bool(v and v["success"] and v["trials"] and all(t["success"] for t in v["trials"])) for v in runs
            ),
            "reasons": sorted({v["reason"] for v in runs if v and not v["success"]}),
        }
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True, help="folder for the datasets (created)")
    p.add_argument("--summarize-only", action="store_true", help="only re-read the datasets in --work")
    p.add_argument("--results", default="ability_hand", help="benchmarks/results/NAME.json")
    args = p.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    w, seconds = args.work, {}
    own, source = w / "ability", w / "source"
    run = ("-o", "validate_sims=[sapien,pybullet]", "--no-progress")
    if not args.summarize_only:
        seconds["prepare"] = ges("hand", "prepare", "ability")
        seconds["ability"] = ges("synth", "--hands", "ability", "--objects", *DEMO_OBJECTS, "--out", str(own), *run)
        seconds["source"] = ges(
            "synth", "--hands", "allegro", "shadow", "--objects", *DEMO_OBJECTS, "--out", str(source), *run,
            "-o", "robust.enabled=false",
        )  # fmt: skip
        for hand in ("allegro", "shadow"):
            seconds[f"from_{hand}"] = ges(
                "retarget", str(source), "--from", hand, "--to", "ability", "--out", str(w / f"from_{hand}"),
                "--no-progress",
            )  # fmt: skip
    rows = {"ability (own contacts)": summarize(own, "ability")}
    for hand in ("allegro", "shadow"):
        rows[f"{hand} (source)"] = summarize(source, hand)
        rows[f"ability from {hand}"] = summarize(w / f"from_{hand}", "ability")
    print(
        f"{'run':24} {'contacts':>9} {'retarget':>9} {'refine':>9}  " + "  ".join(f"{s + ' val/rob':>16}" for s in SIMS)
    )
    for name, row in rows.items():
        steps = " ".join(f"{ok:>4}/{n:<4}" for ok, n in row["steps"].values())
        sims = "  ".join(f"{row['sims'][s]['validated']:>7}/{row['sims'][s]['robust']:<8}" for s in SIMS)
        print(f"{name:24} {steps}  {sims}")
    write_results(
        results,
        {"code": code_state(), "objects": list(DEMO_OBJECTS), "seconds": seconds, "runs": rows},
    )


if __name__ == "__main__":
    main()
