"""``ges evaluate``: GES end to end, the gate picking one expert per object, against every expert and the oracle."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import non_negative_int
from ges_core.cli.cmd_experts import (
    add_episode_options,
    add_fanout_options,
    add_run_options,
    fanout_from_args,
    randomization_text,
    run_from_args,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges evaluate``."""
    p = sub.add_parser(
        "evaluate",
        help="GES end to end: each gate picks an expert per object, the expert runs; Table 2 against the oracle",
        description="For every selected object each --gate reads its point cloud and picks one expert; the "
        "pre-grasp reaching runs and the picked expert executes E episodes (both success protocols). The success "
        "matrix of the experts alone is completed first under the same settings (ges eval-experts' file, reused "
        "where it holds the cells). Writes OUT/ges-HAND-SIM.json after every cell (a rerun resumes), Table 2 "
        "(OUT/table2-HAND-SIM.json, .md) and the expert-fusion figure (OUT/fusion-HAND-SIM.png); docs/evaluate.md.",
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="Stage 1 dataset folder (ges synth / ges demo)")
    p.add_argument(
        "--expert", action="append", default=[], metavar="[LABEL=]NAME[:KEY=VALUE,...]",
        help="an expert GES chooses among, labelled as in the matrix and the gate (repeatable), e.g. "
        "abs=ppo:checkpoint=runs/tiny/experts/expert1/checkpoints/last.pt; default: the experts the first --gate "
        "was trained for (from its training matrix)",
    )  # fmt: skip
    p.add_argument(
        "--gate", action="append", default=[], metavar="[LABEL=]PATH",
        help="a gate checkpoint of ges train-gate (repeatable: one Table 2 row per gate), picking by the rule "
        "stored in it (ges train-gate's pick: the best training expert unless the gate clearly prefers another)",
    )  # fmt: skip
    p.add_argument(
        "--gate-argmax", action="append", default=[], metavar="[LABEL=]PATH",
        help="a gate checkpoint picking by the paper's argmax whatever rule it stores (repeatable; default row "
        "label PLUGIN-argmax): give one path to both --gate and --gate-argmax to compare the two rules",
    )  # fmt: skip
    add_episode_options(p)
    p.add_argument(
        "--matrix", type=Path, metavar="PATH",
        help="success matrix to complete and compare against (default: DATASET/../experts/matrix-HAND-SIM.json)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, metavar="DIR", help="results folder (default: DATASET/../ges)")
    p.add_argument(
        "--reuse-matrix", action="store_true",
        help="take a picked expert's episodes from the matrix instead of running them again where they are provably "
        "the same (same run header, expert and checkpoint hash, grasp, and code stamp); the summary counts them",
    )  # fmt: skip
    p.add_argument(
        "--accept-code", action="append", default=[], metavar="STAMP",
        help="with --reuse-matrix: matrix cells run by this other code stamp (the matrix's cells' 'code') count as "
        "this code's, on your word that nothing since changes an episode (e.g. only gate code changed); repeatable; "
        "the summary lists the code files that differ. Without it, cells of other code are run again",
    )  # fmt: skip
    p.add_argument(
        "--verify-accepted", type=non_negative_int, default=4, metavar="N",
        help="with --accept-code: first rerun N of the cells to be taken under those stamps (spread over the "
        "objects) with this code, and stop, naming them, if any gives other episodes (default 4; 0: take them on your "
        "word alone)",
    )  # fmt: skip
    p.add_argument(
        "--cloud-seed", type=non_negative_int, default=0, metavar="N", help="seed of the gate's cloud samples (0)"
    )
    add_run_options(p)
    add_fanout_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_evaluate)


def run_evaluate(args: argparse.Namespace) -> int:
    """Evaluate, write Table 2 and the figure, print both tables and the summary."""
    from ges_core.cli import registry_from_args
    from ges_core.errors import ConfigError
    from ges_core.experts.matrix import read_matrix_json
    from ges_core.ges_eval import evaluate_ges, parse_gate
    from ges_core.ges_eval.against_best import ges_against_best_table
    from ges_core.ges_eval.gates import gate_experts, training_matrix, transfer_notes
    from ges_core.ges_eval.outputs import write_outputs
    from ges_core.threads import set_torch_threads

    set_torch_threads()
    registry = registry_from_args(args)
    gates = [parse_gate(g) for g in args.gate] + [parse_gate(g, argmax=True) for g in args.gate_argmax]
    given, trained_on = None, None
    if not args.expert and gates:
        path = training_matrix(gates[0])
        matrix = read_matrix_json(path) if path is not None else None
        given = gate_experts(gates[0], registry, matrix)  # the first gate's experts; every gate is checked against them
        print(f"experts from gate {gates[0].path}: {', '.join(c.label for c in given)}")
        if matrix is not None:
            trained_on = (path, matrix.get("run", {}))
            _defaults_from_training_matrix(args, *trained_on)
    if len(given or args.expert) < 2:
        raise ConfigError("ges evaluate needs the experts GES chooses among: --expert LABEL=NAME:... twice or more")
    base = trained_on[1] if trained_on else None
    experts, config = run_from_args(args, registry, "ges evaluate", experts=given, base=base)
    if trained_on and args.matrix is None:
        _matrix_from_training(args, config, *trained_on)
    for line in transfer_notes(gates, config.hand, config.sim):
        print(f"note: {line}")
    report = evaluate_ges(
        args.dataset, config, experts, gates, args.out or args.dataset.parent / "ges",
        matrix_file=args.matrix, registry=registry, progress=not args.no_progress, fanout=fanout_from_args(args),
        reuse_matrix=args.reuse_matrix, accept_code=args.accept_code, verify_accepted=args.verify_accepted,
        cloud_seed=args.cloud_seed,
    )  # fmt: skip
    paths = write_outputs(report, config.model_dump(mode="json"))
    print(f"GES | hand {config.hand} | sim {config.sim} | {config.envs} episode(s) per object | "
          f"{randomization_text(config)}\n")  # fmt: skip
    print(report.table.markdown("paper") + "\n\n" + report.table.markdown("peers") + "\n")
    print(report.table.accuracy_markdown("paper") + "\n")
    for line in report.late:
        print(f"note: {line}")
    if report.against_best:
        print(ges_against_best_table(report.against_best) + "\n(GES is above the best single expert of a split when "
              "the whole interval is; docs/evaluate.md)\n")  # fmt: skip
    for line in report.errors[:10]:
        print(f"error: {line}")
    print(report.summary())
    print(f"Table 2: {paths['json']}, {paths['markdown']}; figure: {paths['figure']}")
    return 0


def _defaults_from_training_matrix(args: argparse.Namespace, matrix: Path, run: dict) -> None:
    """With the experts taken from a gate: the hand, simulator and episodes per cell of ``run``, the header of
    ``matrix``, the one the gate was trained on, where ``--hand``, ``--sim`` and ``--episodes`` are not given (what
    the gate was trained for, not registry.yaml's defaults); each default taken is printed. The header's seed,
    environment (randomization included) and scene settings become the run's base in ``run_from_args``."""
    taken = []
    defaults = {"hand": run.get("hand"), "sim": run.get("sim"), "episodes": run.get("envs")}
    for option, value in defaults.items():
        if getattr(args, option) is None and value:
            setattr(args, option, value)
            taken.append(f"--{option} {value}")
    seeds = f"seed {run['seed']}" if "seed" in run else ""
    if "env" in run:
        seeds += f", env.randomization.seed {run['env'].get('randomization', {}).get('seed')}"
    taken += [f"its {seeds} and environment settings"] if seeds else []
    if taken:
        print(f"from the gate's training matrix {matrix}: {', '.join(taken)}")


def _matrix_from_training(args: argparse.Namespace, config, matrix: Path, run: dict) -> None:
    """``--matrix`` defaults to the gate's training matrix when the run's settings are that matrix's (so its cells are
    completed and reused); with other settings (``-o``, ``--no-randomization``) the default matrix file stays, and
    the settings that differ are printed."""
    from ges_core.dataset.layout import config_differences
    from ges_core.experts.evaluate import run_header

    diffs = config_differences(run, run_header(config))
    if diffs:
        print(f"not completing the gate's training matrix (its run differs: {'; '.join(diffs)}); using the default "
              "--matrix")  # fmt: skip
    else:
        args.matrix = matrix
        print(f"--matrix {matrix} (the gate's training matrix, same run settings)")
