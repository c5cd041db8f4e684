"""``train.folds`` K >= 2: K networks of one gate plugin, each holding out one fold of the objects, averaged.

Why: ``ges train-gate`` chooses the pick rule's margin (:mod:`ges_core.gating.fallback`) on the objects the gate
never trained on. With one split those are ``val_fraction`` of them (34 of the procedural library's 170 training
objects), and which 34 decided the rule: at gate seed 1 three of four gates fitted "always the script" where seed 0
gained 2-4 points (docs/gating.md, "Category smoothing"). With K folds every kept object is scored by the member
that never saw it (its out-of-fold score), the rule is chosen on all of them, and the gate used afterwards scores
with the members' mean probability (:class:`~ges_core.gating.torch_gate.MeanOfMembers`).

The members share the seed: one partition of the objects (:func:`~ges_core.gating.data.fold_indices`), the same
starting weights; they differ by the fold they hold out. The rule's margin is chosen on single members' scores and
applied to their mean, whose gaps are smaller where members disagree: the average leaves the fallback expert no more
readily than its members would have.

Files, per member f: OUT/fold-f/ train_state.pt, tb/, history.json, gate.pt. ``resume`` continues each member from
its state (a finished member is read back, not retrained).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from ges_core.errors import ConfigError
from ges_core.gating.torch_gate import TorchGate
from ges_core.gating.train import GateData, TrainConfig, TrainResult
from ges_core.paths import atomic_write_text
from ges_core.policy import Gate

__all__ = ["FoldsResult", "train_folds"]


@dataclass
class FoldsResult:
    """What :func:`train_folds` leaves besides the members' files."""

    gate: TorchGate
    """The averaged gate (the members' mean probability)."""
    results: list[TrainResult]
    """Per member: its split (``val_ids``: the fold it held out) and curves."""
    out_of_fold: dict[str, torch.Tensor]
    """Object id -> (k,) float32 probabilities from the member that held the object out; every kept object once."""


def train_folds(
    make_gate: Callable[[], Gate],
    data: GateData,
    config: TrainConfig,
    out: Path,
    *,
    resume: bool = False,
    state_every: int = 5,
    on_epoch: Callable[[int, int, TrainResult], None] | None = None,
) -> FoldsResult:
    """Train ``config.folds`` members (``make_gate()``: a fresh, untrained torch gate each) on ``data``, member f
    holding out fold f, into OUT/fold-f (module docs); return the averaged gate and the out-of-fold scores.
    ``on_epoch(fold, epoch, result)`` after each member's epoch. A gate without a network to average (the centroid
    gate) is a ConfigError before anything trains."""
    if config.folds < 2:
        raise ConfigError(f"train_folds needs train.folds >= 2, got {config.folds}")
    members: list[TorchGate] = []
    results: list[TrainResult] = []
    out_of_fold: dict[str, torch.Tensor] = {}
    index = {oid: i for i, oid in enumerate(data.rates.object_ids)}
    for fold in range(config.folds):
        member = make_gate()
        if not isinstance(member, TorchGate):
            raise ConfigError(
                f"train.folds = {config.folds} averages the networks of a point-cloud gate (curvenet, pointnet2); "
                f"gate '{member.name}' has none: train it with train.folds 1"
            )
        where = Path(out) / f"fold-{fold}"
        result = member.fit(
            data,
            config,
            log_dir=where / "tb",
            on_epoch=None if on_epoch is None else (lambda e, r, f=fold: on_epoch(f, e, r)),
            state_file=where / "train_state.pt",
            state_every=state_every,
            resume=resume,
            fold=fold,
        )
        member.save(where / "gate.pt")
        atomic_write_text(where / "history.json", json.dumps(result.history, indent=1) + "\n")
        held_out = result.val_ids
        if held_out:
            probs = member.predict(data.clouds[[index[i] for i in held_out]], held_out)
            out_of_fold.update(zip(held_out, probs, strict=True))
        members.append(member)
        results.append(result)
    info = {
        "config": config.model_dump(mode="json"),
        "folds": [m.train_info for m in members],
        "train_ids": sorted({i for r in results for i in r.train_ids + r.val_ids}),
        "dropped_ids": results[0].dropped_ids,
    }
    return FoldsResult(type(members[0]).averaged(members, info), results, out_of_fold)
