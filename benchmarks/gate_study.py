"""The paper's gate studies on real object clouds: 1024 vs 4096 input points, and training curves per backbone.

Success rates here are NOT from experts: no PPO expert set exists yet, so each object's rates follow a
smooth rule on its real size (longest side L of the resting mesh, metres): expert "small" succeeds with
1 - sigmoid((L - 0.08) / 0.015), "large" with sigmoid((L - 0.13) / 0.015), "medium" with
exp(-((L - 0.105) / 0.025)^2). It tests that each gate learns a geometric preference from the point cloud
(the paper's expert 1 takes small objects, expert 3 large ones), not how well GES grasps. The clouds
(farthest points of the library's procedural objects, object frame) are real.

For each gate (curvenet, pointnet2, centroid) and input size (1024, 4096): ``gate.fit`` with the same
seeded split (25 % validation), epochs and augmentation; train / validation gate accuracy and time. Writes
benchmarks/results/NAME.json and benchmarks/results/NAME_curves.png (loss and validation accuracy per epoch,
per backbone, at the smallest size); default NAME gate_study, whose PNG is gate_curves.png. ``--out NAME``
(the older flag) is the same as ``--results NAME``.

Usage: python benchmarks/gate_study.py [--per-category 3] [--epochs 20] [--sizes 1024 4096] [--replot]
       [--gates curvenet ...] [--settings '{"curvenet": {"k": 10}}'] [--results NAME]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ges_core.gating import GateData, SuccessRates, TrainConfig, fit_cloud, library_clouds  # noqa: E402
from ges_core.objects.library import LibraryConfig, ObjectLibrary  # noqa: E402
from ges_core.registry import load_registry  # noqa: E402

from _results import code_state, results_path, write_results  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"
EXPERTS = ("small", "medium", "large")


def size_rule(longest: np.ndarray) -> np.ndarray:
    """(n, 3) success rates of the three rule 'experts' from the longest side (m); see the module docstring."""
    sig = 1.0 / (1.0 + np.exp(-(longest - 0.08) / 0.015))
    big = 1.0 / (1.0 + np.exp(-(longest - 0.13) / 0.015))
    mid = np.exp(-(((longest - 0.105) / 0.025) ** 2))
    return np.clip(np.stack([1.0 - sig, mid, big], axis=1), 0.0, 1.0)


def dataset(per_category: int, sizes: list[int]) -> dict[int, GateData]:
    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=per_category))
    ids = [o.object_id for o in library.list()]
    rates = SuccessRates(ids, EXPERTS, size_rule(np.array([library.extents(i).max() for i in ids])))
    cache = Path(__file__).resolve().parent.parent / "runs" / f"gate_study_clouds_{per_category}_{max(sizes)}.pt"
    if cache.is_file():
        big = torch.load(cache, weights_only=True)
    else:  # sampling 4096 farthest points of 16384 per object is minutes for the set: kept for reruns
        big = library_clouds(library, ids, max(sizes))
        cache.parent.mkdir(parents=True, exist_ok=True)
        torch.save(big, cache)
    out = {}
    for n in sizes:
        clouds = torch.stack([torch.from_numpy(fit_cloud(c.numpy(), n, i)) for c, i in zip(big, ids, strict=True)])
        out[n] = GateData(rates, clouds)
    return out


GATES = ("centroid", "pointnet2", "curvenet")  # cheapest first: a stopped run has whole comparisons


def run(
    registry, data: dict[int, GateData], epochs: int, save, gates=GATES, overrides: dict | None = None
) -> tuple[list[dict], dict]:
    """Fit every gate at every size; ``save(rows, curves)`` after each (a stopped run keeps what it did).
    ``overrides``: per gate name, settings that replace the registered defaults."""
    rows, curves = [], {}
    config = TrainConfig(epochs=epochs, batch_size=8, val_fraction=0.25, seed=0)
    for name in gates:
        for n, d in data.items():
            settings = {**registry.settings("gate", name), **(overrides or {}).get(name, {}), "n_points": n}
            gate = registry.spec("gate", name).load()(**settings)
            start = time.perf_counter()
            result = gate.fit(d, config)
            seconds = time.perf_counter() - start
            s = result.summary()
            rows.append({"gate": name, "points": n, "accuracy_train": s["accuracy/train"],
                         "accuracy_val": s["accuracy/val"], "kept_epoch": result.kept_epoch,
                         "n_train": s["n_train"], "n_val": s["n_val"], "seconds": seconds})  # fmt: skip
            print(f"{name:10s} {n:5d}: train {s['accuracy/train']:.3f} val {s['accuracy/val']:.3f} ({seconds:.0f} s)")
            if n == min(data):
                curves[name] = result.history
            save(rows, curves)
    return rows, curves


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_loss, ax_acc) = plt.subplots(1, 2, figsize=(10, 4))
    for name, history in curves.items():
        if len(history) < 2:
            continue  # the centroid gate has no epochs
        epochs = [h["epoch"] for h in history]
        ax_loss.plot(epochs, [h["loss/train"] for h in history], label=f"{name} train")
        ax_loss.plot(epochs, [h["loss/val"] for h in history], "--", label=f"{name} val")
        ax_acc.plot(epochs, [h["accuracy/train"] for h in history], label=f"{name} train")
        ax_acc.plot(epochs, [h["accuracy/val"] for h in history], "--", label=f"{name} val")
    ax_loss.set(xlabel="epoch", ylabel="KL loss (nats)", title="gate loss (1024 points)")
    ax_acc.set(xlabel="epoch", ylabel="gate accuracy", title="pick among the best experts", ylim=(0, 1.05))
    for ax in (ax_loss, ax_acc):
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def table(rows: list[dict]) -> str:
    lines = ["| gate | points | train acc | val acc | kept epoch | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['gate']} | {r['points']} | {100 * r['accuracy_train']:.1f} % | {100 * r['accuracy_val']:.1f} % "
            f"| {r['kept_epoch']} | {r['seconds']:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-category", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--replot", action="store_true", help="only redraw the PNG from gate_study.json")
    parser.add_argument("--gates", nargs="+", default=list(GATES), choices=GATES)
    parser.add_argument(
        "--settings", default="{}", help='JSON: per gate, settings replacing the defaults, e.g. {"curvenet": {"k": 10}}'
    )
    parser.add_argument(
        "--results",
        "--out",
        dest="results",
        default="gate_study",
        help="benchmarks/results/NAME.json and NAME_curves.png (gate_curves.png for gate_study); "
        "--out NAME is an older alias",
    )
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the fits
    if args.replot:
        plot(json.loads(results.read_text())["curves"], OUT / _png(args.results))
        return
    overrides = json.loads(args.settings)
    torch.set_num_threads(1)
    data = dataset(args.per_category, args.sizes)
    n_objects = len(next(iter(data.values())).rates.object_ids)

    def save(rows: list[dict], curves: dict) -> None:
        write_results(
            results,
            {
                "benchmark": "gate_study",
                "rates": "size rule on real object extents (module docstring), not expert evaluations",
                "objects": n_objects,
                "epochs": args.epochs,
                "settings_overrides": overrides,
                "code": code_state(),
                "rows": rows,
                "table": table(rows),
                "curves": curves,
            },
        )

    rows, curves = run(load_registry(), data, args.epochs, save, args.gates, overrides)
    print(table(rows))
    plot(curves, OUT / _png(args.results))


def _png(out: str) -> str:
    return "gate_curves.png" if out == "gate_study" else f"{out}_curves.png"


if __name__ == "__main__":
    main()
