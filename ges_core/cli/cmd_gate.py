"""``ges train-gate``: train an expert-selection gate on a success matrix (``ges eval-experts``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import non_negative_int, positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges train-gate``."""
    p = sub.add_parser(
        "train-gate",
        help="train a gate (curvenet, pointnet2, centroid) on an objects x experts success matrix",
        description="Trains an expert-selection gate: each object's point cloud (farthest-point samples, object "
        "frame) -> a distribution over the matrix's experts, fitted to the normalized success rates with the "
        "paper's KL loss. Writes OUT/gate.pt (atomic checkpoints), OUT/train_state.pt (what --resume continues "
        "from), OUT/tb (TensorBoard), OUT/history.json and OUT/summary.json, and prints the gate accuracy per "
        "split. See docs/gating.md.",
    )
    p.add_argument("matrix", type=Path, nargs="+", metavar="MATRIX",
                   help="success matrix JSON written by ges eval-experts; several (the same objects and experts "
                   "under other seeds): their episodes are pooled into the targets")  # fmt: skip
    p.add_argument("--experts", metavar="A,B,...", help="the expert columns to choose among (default: every column "
                   "but the scripted baseline's)")  # fmt: skip
    p.add_argument("--dataset", type=Path, metavar="DIR", help="Stage 1 dataset whose library holds the objects "
                   "(default: the matrix's run.dataset)")  # fmt: skip
    p.add_argument("--gate", metavar="NAME", help="gate plugin (default: the config's, curvenet)")
    p.add_argument("--config", type=Path, metavar="YAML", help="a TrainGateConfig YAML (docs/gating.md)")
    p.add_argument("--out", type=Path, metavar="DIR", help="run folder (default: MATRIX's folder/gate-<gate>)")
    p.add_argument("--points", type=positive_int, metavar="N", help="points per cloud (default 1024)")
    p.add_argument("--epochs", type=positive_int, metavar="N", help="training epochs (default: the config's)")
    p.add_argument("--seed", type=non_negative_int, metavar="N", help="seed of weights, split, batches, augmentation")
    p.add_argument("--folds", type=positive_int, metavar="K", help="K >= 2: one network per fold of the objects, "
                   "averaged into one gate, the pick rule chosen on every object's out-of-fold score (default 1: "
                   "one network, train.val_fraction held out; docs/gating.md, 'Folds')")  # fmt: skip
    p.add_argument("--distill", action="store_true", help="with --folds K: then train one network towards the K "
                   "networks' averaged scores and store it as OUT/gate.pt (one network's inference time; the average "
                   "kept as OUT/averaged.pt; docs/gating.md, 'Distilled')")  # fmt: skip
    p.add_argument("--distill-epochs", type=positive_int, metavar="N", help="with --distill: epochs of the distilled "
                   "network (default: --epochs, the members')")  # fmt: skip
    p.add_argument("--no-augment", action="store_true", help="train on the clouds as sampled (no rotation/scaling)")
    p.add_argument("--resume", action="store_true", help="continue a killed run from OUT/train_state.pt (written with "
                   "each checkpoint); it ends as if it had never stopped")  # fmt: skip
    p.add_argument(
        "-o", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
        help="override a TrainGateConfig value, e.g. train.lr=5e-4 or settings.k=20 (the gate plugin's settings)",
    )  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_gate_cmd)


def run_gate_cmd(args: argparse.Namespace) -> int:
    """Build the config, train, print the summary table."""
    from ges_core.cli import registry_from_args
    from ges_core.gating.run import config_from_args, train_gate_run
    from ges_core.threads import set_torch_threads

    set_torch_threads()  # ges --threads / $GES_THREADS / 1 (ges_core.threads)
    config = config_from_args(args)
    summary = train_gate_run(config, registry_from_args(args), resume=args.resume, progress=not args.no_progress)
    print(summary.table())
    return 0
