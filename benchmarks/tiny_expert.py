"""The ``tiny`` expert runs: wall time, env steps and the success curve, read from their run folders.

Reads ``history.jsonl`` and ``summary.json`` of each ``ges train-expert`` run folder given (default: every run
under ``runs/tiny/experts``), prints a table of the success rate (paper protocol, per episode) in bins of
iterations with the curriculum stage (and the in-run evaluations of ``evaluations.jsonl`` where the run had them,
dashed in the PNG), writes ``benchmarks/results/tiny_expert.json`` and a PNG of the curves
(``benchmarks/results/tiny_expert.png``). The training itself is ``ges train-expert`` (docs/training.md):

    ges train-expert runs/tiny/dataset --cluster 1 --out runs/tiny/experts/expert1
    ges train-expert runs/tiny/dataset --cluster 1 -o action_mode=residual --out runs/tiny/experts/expert1_residual
    ges train-expert runs/tiny/dataset --cluster 1 -o warm_start.enabled=true -o warm_start.anchor_steps=10 \
        --out runs/tiny/experts/expert1_abs_bc_anchor
    python benchmarks/tiny_expert.py [RUN_DIR ...] [--bin 25] [--matrix MATRIX.json ...] [--results NAME --title T]

``--matrix``: success matrices of ``ges eval-experts`` (randomization on, and the ``-norand`` file for off): their
per-split table (paper and peers protocols) goes into the results beside the curves. ``--results NAME``: another
results file, ``benchmarks/results/NAME.json`` (its PNG beside it), for runs other than runs/tiny's; ``--title`` the
figure's title.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _results import code_state, results_path, write_results

ROOT = Path(__file__).resolve().parent.parent


LABELS = {
    "expert1": "absolute, cold start (the paper's action, PPO from scratch; before the warm start)",
    "expert1_residual": "residual on the scripted expert",
    "expert1_abs_bconly": "absolute, behaviour cloning only (warm start, 1 critic iteration, no PPO update)",
    "expert1_abs_bc": "absolute, warm start + PPO without anchor (stopped by hand at 83 iterations)",
    "expert1_abs_bc_anchor": "absolute, warm start + PPO with anchor_steps 10",
    "expert1_abs_bc36k_anchor": "absolute, warm start on 36,864 demonstration samples + PPO with anchor_steps 10",
}
"""What each run folder under runs/tiny/experts is (folders not listed are labelled by name)."""


def read_run(folder: Path) -> dict:
    """One run's label, config, summary, warm-start record and per-iteration rows."""
    rows = [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines() if line.strip()]
    summary = json.loads((folder / "summary.json").read_text()) if (folder / "summary.json").is_file() else None
    config = (folder / "config.yaml").read_text() if (folder / "config.yaml").is_file() else ""
    warm = folder / "warm_start.json"
    warm_start = json.loads(warm.read_text()) if warm.is_file() else None
    if warm_start:
        loss = warm_start.pop("imitation_loss")
        warm_start["imitation_loss_first_last"] = [loss[0], loss[-1]]
    return {"run": folder.name, "label": LABELS.get(folder.name, folder.name), "rows": rows, "summary": summary,
            "warm_start": warm_start, "config_yaml": config, "evaluations": read_evaluations(folder, rows)}  # fmt: skip


def read_evaluations(folder: Path, rows: list[dict]) -> list[dict]:
    """The run's in-run evaluations (``evaluations.jsonl``, ``evaluation.interval``): iteration, env steps then,
    noise-free success under both protocols, episodes, the training episodes' success over the same iterations
    since the previous evaluation (the noisy curve's figure beside it); [] when the run had none."""
    path = folder / "evaluations.jsonl"
    if not path.is_file():
        return []
    out, since = [], 0
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        e = json.loads(line)
        span = [r for r in rows if since < r["iteration"] <= e["iteration"]]
        episodes = sum(r["episodes"] for r in span)
        wins = sum(round((r["success_paper"] or 0) * r["episodes"]) for r in span)
        out.append({
            "iteration": e["iteration"], "env_steps": span[-1]["env_steps"] if span else None,
            "success_paper": e["success_paper"], "success_peers": e["success_peers"], "episodes": e["episodes"],
            "best": e["best"], "training_success_paper": round(wins / episodes, 3) if episodes else None,
        })  # fmt: skip
        since = e["iteration"]
    return out


def read_matrix(path: Path) -> dict:
    """Per split and protocol, each expert column's success rate and episodes, from a ges eval-experts matrix."""
    from ges_core.experts.matrix import load_matrix
    from ges_core.experts.table import expert_table, split_rates
    from ges_core.objects.splits import SPLITS

    matrix = load_matrix(path)
    out = {"matrix": str(path), "experts": list(matrix.experts), "splits": {}}
    for split in (*SPLITS, None):
        rows = matrix.rows(split)
        out["splits"][split or "all"] = {
            "objects": int(rows.sum()),
            "episodes": [int(x) for x in matrix.episodes[rows].sum(axis=0)],
            **{p: split_rates(matrix, p, split) for p in ("paper", "peers")},
        }
    out["table_paper"] = expert_table(matrix, "paper")
    out["table_peers"] = expert_table(matrix, "peers")
    return out


def bins(rows: list[dict], size: int) -> list[dict]:
    """Per ``size`` iterations of a run's history.jsonl: episodes, successes (paper protocol), success (paper,
    peers) over those episodes, mean episode reward, stage at the end, env steps (also benchmarks/ablations.py)."""
    out = []
    for start in range(0, len(rows), size):
        chunk = rows[start : start + size]
        episodes = sum(r["episodes"] for r in chunk)
        paper = sum(round((r["success_paper"] or 0) * r["episodes"]) for r in chunk)
        peers = sum(round((r["success_peers"] or 0) * r["episodes"]) for r in chunk)
        rewards = [r["mean_reward"] for r in chunk if r.get("mean_reward") is not None]
        out.append({
            "iterations": f"{chunk[0]['iteration']}-{chunk[-1]['iteration']}", "env_steps": chunk[-1]["env_steps"],
            "seconds": chunk[-1]["seconds"], "stage": chunk[-1]["stage"], "episodes": episodes, "successes": paper,
            "success_paper": round(paper / episodes, 3) if episodes else None,
            "success_peers": round(peers / episodes, 3) if episodes else None,
            "mean_reward": round(float(sum(rewards) / len(rewards)), 2) if rewards else None,
        })  # fmt: skip
    return out


def plot(runs: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for run in runs:
        b = [x for x in run["bins"] if x["success_paper"] is not None]
        (line,) = ax.plot([x["env_steps"] for x in b], [x["success_paper"] for x in b], marker="o",
                          label=f"{run['run']}: {run['label'].split(' (')[0]}")  # fmt: skip
        e = [x for x in run["evaluations"] if x["env_steps"] is not None and x["success_paper"] is not None]
        if e:
            ax.plot([x["env_steps"] for x in e], [x["success_paper"] for x in e], marker="s", linestyle="--",
                    color=line.get_color(), label=f"{run['run']}: in-run evaluation (noise-free)")  # fmt: skip
    ax.set_xlabel("env steps")
    ax.set_ylabel("success (paper protocol, per episode)")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", type=Path)
    parser.add_argument("--bin", type=int, default=25, help="iterations per row of the table")
    parser.add_argument("--matrix", type=Path, nargs="*", default=[], help="ges eval-experts matrices to tabulate")
    parser.add_argument(
        "--results", default="tiny_expert", help="benchmarks/results/NAME.json, the PNG beside it (default tiny_expert)"
    )
    parser.add_argument("--title", default="tiny experts (Allegro, SAPIEN, cluster 1)", help="the figure's title")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, before any work
    picture = results.with_suffix(".png")
    folders = args.runs or sorted(p for p in (ROOT / "runs" / "tiny" / "experts").iterdir() if p.is_dir())
    runs = []
    for folder in folders:
        run = read_run(folder)
        run["bins"] = bins(run["rows"], args.bin)
        runs.append(run)
        s = run["summary"] or {}
        print(f"\n{run['run']} ({run['label']}): {s.get('iterations')} iterations, {s.get('env_steps')} env steps, "
              f"{s.get('seconds')} s, stopped {s.get('stopped')}, stage {s.get('stage')}")  # fmt: skip
        print("| iterations | env steps | s | stage | episodes | success (paper) | success (peers) |")
        print("|---|---|---|---|---|---|---|")
        for b in run["bins"]:
            print(f"| {b['iterations']} | {b['env_steps']:,} | {b['seconds']:.0f} | {b['stage']} | {b['episodes']} | "
                  f"{b['success_paper']} | {b['success_peers']} |")  # fmt: skip
        if run["evaluations"]:
            print("| iteration | env steps | evaluation (paper) | (peers) | episodes | training episodes since |")
            print("|---|---|---|---|---|---|")
            for e in run["evaluations"]:
                print(f"| {e['iteration']}{' (best)' if e['best'] else ''} | {e['env_steps']:,} | "
                      f"{e['success_paper']} | {e['success_peers']} | {e['episodes']} | "
                      f"{e['training_success_paper']} |")  # fmt: skip
    plot(runs, picture, args.title)
    for run in runs:
        del run["rows"]  # the curve is in bins; history.jsonl stays in the run folder
    evals = []
    for path in args.matrix:
        ev = read_matrix(path)
        print(f"\n{path} ({'randomization off' if 'norand' in path.name else 'randomization on'})")
        print(ev["table_paper"])
        print(ev["table_peers"])
        evals.append(ev)
    write_results(results, {"benchmark": "tiny_expert", "runs": runs, "evaluations": evals,
                                 "picture": picture.name, "code": code_state()})  # fmt: skip


if __name__ == "__main__":
    main()
