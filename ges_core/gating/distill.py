"""``train.distill`` (with ``train.folds`` K >= 2): the K averaged networks distilled into one network.

Why: a gate of K networks runs K networks per object (five CurveNets at 1024 points: 52.8 ms on one core against
the issue's 10 ms; docs/gating.md, "Speed"). One more network of the same plugin and settings is trained on every
kept object towards the averaged gate's probabilities (the teacher's scores of the unaugmented clouds; the batches
augmented as in any training, no validation split, the last epoch kept), and it becomes the gate: one network's
inference time.

The pick rule stays the one chosen on the members' out-of-fold scores (:mod:`ges_core.gating.folds`): the student
imitates the average, and every kept object is in its training set, so it has no held-out scores of its own.

Files: OUT/distilled/ train_state.pt, tb/, history.json. ``resume`` continues the student from its state; a state
written for another teacher is refused (its targets are part of the state's identity).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from ges_core.gating.fallback import PickRule
from ges_core.gating.torch_gate import TorchGate
from ges_core.gating.train import GateData, TrainConfig, TrainResult
from ges_core.paths import atomic_write_text

__all__ = ["agreement_of", "distill", "student_config"]


def student_config(config: TrainConfig) -> TrainConfig:
    """The student's training settings: ``config``'s (batches, learning rate, augmentation, seed; epochs
    ``distill_epochs``, else the members') on every kept object, no validation split, the last epoch kept, no
    category smoothing (the teacher's targets carry it)."""
    update = {"folds": 1, "distill": False, "distill_epochs": None, "val_fraction": 0.0, "keep": "last"}
    return config.model_copy(update=update | {"category_smoothing": 0.0, "epochs": config.student_epochs})


def distill(
    make_gate: Callable[[], TorchGate],
    teacher: TorchGate,
    data: GateData,
    config: TrainConfig,
    out: Path,
    *,
    resume: bool = False,
    state_every: int = 5,
    on_epoch: Callable[[int, TrainResult], None] | None = None,
) -> tuple[TorchGate, TrainResult]:
    """Train ``make_gate()`` (a fresh gate of the teacher's plugin and settings) on ``data`` towards ``teacher``'s
    probabilities of ``data.clouds`` (metres) into OUT/distilled (module docs); return it and its curves. Its
    ``train_info`` names the teacher's members and training settings."""
    student = make_gate()
    soft = teacher.predict(data.clouds, data.rates.object_ids).double()
    soft = soft / soft.sum(dim=1, keepdim=True)  # float32 rows summing to 1 within 1e-7, exactly in float64
    where = Path(out) / "distilled"
    result = student.fit(
        data,
        student_config(config),
        log_dir=where / "tb",
        on_epoch=on_epoch,
        state_file=where / "train_state.pt",
        state_every=state_every,
        resume=resume,
        soft_targets=soft,
    )
    student.train_info["distilled_from"] = {"members": teacher.members, "train": teacher.train_info}
    atomic_write_text(where / "history.json", json.dumps(result.history, indent=1) + "\n")
    return student, result


def agreement_of(rule: PickRule, experts: Sequence[str], a: torch.Tensor, b: torch.Tensor) -> dict[str, float]:
    """How often two gates' (n, k) scores of the same objects pick the same expert: ``pick`` by ``rule``,
    ``argmax`` by the argmax (fractions of the n objects; NaN for n = 0)."""
    if not len(a):
        return {"pick": float("nan"), "argmax": float("nan")}
    return {
        "pick": float(np.mean(rule.choose(a, experts) == rule.choose(b, experts))),
        "argmax": float((a.argmax(dim=1) == b.argmax(dim=1)).double().mean()),
    }
