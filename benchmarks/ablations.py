"""The paper's two Stage 2 ablations on the ``tiny`` preset: rewards (Table 3) and priors (the priors figure).

**Reward** (``--study reward``): one expert per reward preset (``udgr``, ``tsr``, ``tsr_scr``; ges_core/env/reward.py),
same seed, objects, curriculum and iteration budget; then ``ges eval-experts`` runs the three (and the scripted
baseline) on every object of the three splits with randomization on, and the table gives success (paper and
peers protocols) and the Table 3 metrics per episode (arm oscillation, hand oscillation, FDC; ges_core/env/metrics.py)
averaged over every episode. The paper's claim: TSR+SCR has the lowest oscillation.

**Prior** (``--study prior``): Init/NoInit x Goal/NoGoal (``env.init_prior``, ``env.goal_prior``): success
against environment steps from each run's ``history.jsonl``, one PNG, as the paper's ablation figure.

Each training run is ``ges train-expert`` in a subprocess (skipped when its run folder already has a summary with
the asked iterations: rerunning the script resumes), each evaluation ``ges eval-experts`` (resumable itself).

    python benchmarks/ablations.py --study reward [--iterations 150] [--action-mode residual] [--episodes 4]
        [--scr-scale 4 10]   # more TSR+SCR arms, both penalty weights times each factor (tsr_scr_x4, ...)
        [--results NAME]
    python benchmarks/ablations.py --study prior [--iterations 150] [--action-mode absolute] [--warm-start]
        [--results NAME]

Results: ``benchmarks/results/NAME.json`` (+ ``NAME.png`` for the prior study), NAME by default
``ablation_<study>`` and its suffixes below (``--results NAME`` replaces the whole name); runs under
``runs/ablations/<study>/``. ``--seed N`` (N > 0) trains and evaluates in folders of their own (``<arm>-seedN``,
``eval-seedN``) and writes ``ablation_<study>_seedN.json``: another seed never reuses seed 0's runs. The
scripted expert needs the goal in the observation, so the residual action mode cannot run the NoGoal arms of the
prior study: that study uses the absolute (paper's) action. ``--warm-start`` starts every arm from the
behaviour-cloning warm start (``warm_start.enabled=true``; a NoGoal arm clones a teacher that sees the goal its
policy does not); its runs and results are named ``-warm`` / ``_warm``. ``-o KEY=VALUE`` changes every arm and needs
``--tag NAME`` (runs and results named ``-NAME``), so tagged runs never mix with untagged ones. The results record
the dataset trained on (record count and manifest SHA-256).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tiny_expert import bins

from ges_core.env.reward import REWARD_PRESETS
from ges_core.experts.matrix import load_matrix
from ges_core.experts.table import split_rates
from ges_core.objects.splits import SPLITS

from _results import code_state, results_path, write_results

ROOT = Path(__file__).resolve().parent.parent
REWARD_ARMS = {"udgr": ["reward_preset=udgr"], "tsr": ["reward_preset=tsr"], "tsr_scr": ["reward_preset=tsr_scr"]}
PRIOR_ARMS = {
    "init_goal": ["env.init_prior=true", "env.goal_prior=true"],
    "init_nogoal": ["env.init_prior=true", "env.goal_prior=false"],
    "noinit_goal": ["env.init_prior=false", "env.goal_prior=true"],
    "noinit_nogoal": ["env.init_prior=false", "env.goal_prior=false"],
}
METRICS = ("arm_oscillation", "hand_oscillation", "fdc")


def ges(*args: str) -> None:
    """Run ``ges ARGS`` from the repository root; its output goes to ours; a failure stops the study."""
    cmd = [sys.executable, "-m", "ges_core.cli", *args]
    print("$ ges " + " ".join(args), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})


def _suffix(args: argparse.Namespace) -> str:
    """'' for seed 0 without the warm start or a tag (the runs and results as first written), else '-warm', '-<tag>'
    and/or '-seed<N>': another seed, the warm start or another tag never reuses them."""
    tag = f"-{args.tag}" if args.tag else ""
    return ("-warm" if args.warm_start else "") + tag + (f"-seed{args.seed}" if args.seed else "")


def train(study: str, arm: str, overrides: list[str], args: argparse.Namespace) -> Path:
    """Train one arm (or reuse a finished run of the same budget and seed); its run folder."""
    out = ROOT / "runs" / "ablations" / study / f"{arm}{_suffix(args)}"
    summary = out / "summary.json"
    if summary.is_file() and json.loads(summary.read_text()).get("iterations", 0) >= args.iterations:
        print(f"{arm}: reusing {out.relative_to(ROOT)}", flush=True)
        return out
    warm = ["warm_start.enabled=true"] if args.warm_start else []
    opts = [f"action_mode={args.action_mode}", f"iterations={args.iterations}", "time_limit=null", *warm, *overrides,
            *args.override]  # fmt: skip
    resume = ["--resume"] if (out / "checkpoints").is_dir() else []
    cli = ["train-expert", str(args.dataset), "--cluster", str(args.cluster), "--seed", str(args.seed),
           "--envs", str(args.envs), "--out", str(out), "--no-progress", *resume]  # fmt: skip
    for o in opts:
        cli += ["-o", o]
    ges(*cli)
    return out


def dataset_fingerprint(folder: Path) -> dict:
    """What identifies the dataset the arms trained on: its record count and the SHA-256 (16 hex digits) of its
    manifest (every record's file, outcome per step and step times, and the run config): a dataset regenerated by
    newer Stage 1 code reads another, so results of different days can be told apart."""
    manifest = Path(folder) / "manifest.json"
    if not manifest.is_file():
        raise SystemExit(f"--dataset {folder}: no manifest.json there (ges synth and ges demo write one in theirs)")
    data = manifest.read_bytes()
    return {"path": str(folder), "manifest_sha256": hashlib.sha256(data).hexdigest()[:16],
            "records": len(json.loads(data).get("records", []))}  # fmt: skip


def history(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "history.jsonl").read_text().splitlines() if line.strip()]


def reward_table(matrix_file: Path, arms: list[str]) -> list[dict]:
    """Per column of the matrix: success rates (ges_core.experts.table.split_rates: every episode pooled) and the
    mean and median Table 3 metrics over every episode of every split."""
    data, m = json.loads(matrix_file.read_text()), load_matrix(matrix_file)  # the metrics are in the raw cells
    overall = {p: split_rates(m, p) for p in ("paper", "peers")}
    by_split = {s: split_rates(m, "paper", s) for s in sorted(SPLITS)}
    rows = []
    for label in [*arms, m.baseline]:
        j = m.experts.index(label)
        row = {"expert": label, "objects": int((m.episodes[:, j] > 0).sum()), "episodes": int(m.episodes[:, j].sum())}
        row |= {f"success_{p}": round(overall[p][label] or 0.0, 3) for p in overall}
        row["success_paper_by_split"] = {s: round(r[label], 3) for s, r in by_split.items() if r[label] is not None}
        values = {name: [] for name in METRICS}
        for cell in (c[label] for c in data["cells"].values() if label in c):
            for name in METRICS:
                values[name] += [v for v in cell.get("metrics", {}).get(name, []) if v is not None]
        for name, v in values.items():
            row[name] = round(float(np.mean(v)), 2) if v else None
            row[f"{name}_median"] = round(float(np.median(v)), 2) if v else None
        rows.append(row)
    return rows


def scr_arms(scales: list[float]) -> dict[str, list[str]]:
    """TSR+SCR arms with both penalty weights (ges_core/env/reward.py's ``tsr_scr`` preset) times each factor."""
    base = REWARD_PRESETS["tsr_scr"]
    return {
        f"tsr_scr_x{m:g}": [
            "reward_preset=custom",
            f"env.reward.w_smooth={base.w_smooth * m:g}",
            f"env.reward.w_consistency={base.w_consistency * m:g}",
        ]
        for m in scales
    }


def run_reward(args: argparse.Namespace) -> dict:
    arms = {**REWARD_ARMS, **scr_arms(args.scr_scale)}
    runs = {arm: train("reward", arm, o, args) for arm, o in arms.items()}
    out = ROOT / "runs" / "ablations" / "reward" / f"eval{_suffix(args)}"
    cli = ["eval-experts", str(args.dataset), "--hand", "allegro", "--sim", "sapien", "--episodes", str(args.episodes),
           "--out", str(out), "--no-progress"]  # fmt: skip
    for arm, run in runs.items():
        cli += ["--expert", f"{arm}=ppo:checkpoint={run / 'checkpoints' / 'last.pt'}"]
    ges(*cli)
    rows = reward_table(out / "matrix-allegro-sapien.json", list(runs))
    print(f"\n{'expert':<10} {'episodes':>8} {'paper':>6} {'peers':>6} {'arm osc':>9} {'hand osc':>9} {'FDC':>8}   "
          "paper by split")  # fmt: skip
    for r in rows:
        print(f"{r['expert']:<10} {r['episodes']:>8} {r['success_paper']:>6.3f} {r['success_peers']:>6.3f} "
              f"{_num(r['arm_oscillation']):>9} {_num(r['hand_oscillation']):>9} {_num(r['fdc']):>8}   "
              f"{r['success_paper_by_split']}")  # fmt: skip
    curves = {arm: bins(history(run), 10) for arm, run in runs.items()}
    return {"rows": rows, "curves": curves, "matrix": str(out / "matrix-allegro-sapien.json")}


def run_prior(args: argparse.Namespace, results: Path) -> dict:
    runs = {arm: train("prior", arm, o, args) for arm, o in PRIOR_ARMS.items()}
    curves = {arm: bins(history(run), 10) for arm, run in runs.items()}
    picture = results.with_suffix(".png")  # beside the results JSON, named after it
    _plot(curves, picture, args)
    print(f"\n{'arm':<14} {'env steps':>10} {'episodes':>9} {'success (last 20 %)':>20} {'best bin':>9}")
    for arm, c in curves.items():
        tail = c[-max(1, len(c) // 5) :]
        eps = sum(b["episodes"] for b in tail)
        rate = sum(b["successes"] for b in tail) / eps if eps else float("nan")
        best = max((b["success_paper"] for b in c if b["success_paper"] is not None), default=float("nan"))
        print(f"{arm:<14} {c[-1]['env_steps'] if c else 0:>10} {sum(b['episodes'] for b in c):>9} {rate:>20.3f} "
              f"{best:>9.3f}")  # fmt: skip
    return {"curves": curves, "picture": str(picture)}


def _plot(curves: dict, path: Path, args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, rx) = plt.subplots(1, 2, figsize=(12, 4))
    for arm, c in curves.items():
        b = [x for x in c if x["success_paper"] is not None]
        ax.plot([x["env_steps"] for x in b], [x["success_paper"] for x in b], marker=".", label=arm)
        r = [x for x in c if x["mean_reward"] is not None]
        rx.plot([x["env_steps"] for x in r], [x["mean_reward"] for x in r], marker=".", label=arm)
    ax.set_xlabel("env steps")
    ax.set_ylabel("success (paper protocol, training episodes)")
    ax.set_ylim(-0.02, 1.02)
    ax.legend()
    rx.set_xlabel("env steps")
    rx.set_ylabel("mean episode reward (rsl-rl)")
    rx.legend()
    warm = ", behaviour-cloning warm start" if args.warm_start else ""
    fig.suptitle(f"prior ablation: tiny, Allegro, SAPIEN, cluster {args.cluster}, {args.action_mode} actions{warm}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _num(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", choices=("reward", "prior"), required=True)
    parser.add_argument("--dataset", type=Path, default=ROOT / "runs" / "tiny" / "dataset")
    parser.add_argument("--cluster", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=150, help="PPO iterations per arm (the same budget each)")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=4, help="reward study: episodes per object and expert")
    parser.add_argument(
        "--action-mode",
        default=None,
        choices=("absolute", "residual"),
        help="default: residual for reward, absolute for prior (NoGoal has no residual base)",
    )
    parser.add_argument(
        "--scr-scale",
        type=float,
        nargs="*",
        default=[],
        help="reward study: also train TSR+SCR with both penalty weights times each factor",
    )
    parser.add_argument(
        "--warm-start",
        action="store_true",
        help="absolute actions: every arm starts from the behaviour-cloning warm start (NoGoal arms clone a teacher "
        "that sees the goal); runs and results get '-warm' / '_warm' in their names",
    )
    parser.add_argument("-o", action="append", default=[], dest="override", help="more TrainConfig overrides")
    parser.add_argument(
        "--tag", default="", help="a name for runs with other -o overrides: runs and results get '-TAG'"
    )
    parser.add_argument(
        "--results",
        default=None,
        help="benchmarks/results/NAME.json (and NAME.png for the prior study); default "
        "ablation_<study>[_warm][_<tag>][_seed<N>]",
    )
    args = parser.parse_args()  # fmt: skip
    if args.override and not args.tag:
        parser.error(
            "-o changes the arms: give --tag NAME too, so their runs and results do not mix with the untagged ones"
        )
    if args.tag and not re.fullmatch(r"[A-Za-z0-9_-]+", args.tag):
        parser.error(f"--tag {args.tag!r}: letters, digits, '-' and '_' only (it names folders and files)")
    args.action_mode = args.action_mode or ("residual" if args.study == "reward" else "absolute")
    if args.warm_start and args.action_mode == "residual":
        parser.error("--warm-start is for absolute actions (a residual run already starts at its base expert)")
    path = results_path(args.results or f"ablation_{args.study}{_suffix(args).replace('-', '_')}")  # before the runs
    start = time.perf_counter()
    dataset = dataset_fingerprint(args.dataset)  # before the runs: a folder without a manifest stops here, not after
    body = run_reward(args) if args.study == "reward" else run_prior(args, path)
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
    result = {"benchmark": f"ablation_{args.study}", "settings": settings, "dataset": dataset, **body,
              "wall_seconds": round(time.perf_counter() - start, 1), "load_after": os.getloadavg()[0],
              "code": code_state()}  # fmt: skip
    write_results(path, result)
    print(f"\nwrote {path} ({result['wall_seconds']} s)")


if __name__ == "__main__":
    main()
