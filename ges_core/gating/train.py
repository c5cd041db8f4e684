"""Training a torch gate with the paper's KL loss: seeded batches, validation split, TensorBoard curves.

One epoch: the training objects in a seeded random order, in batches of ``batch_size`` to
``2 batch_size - 1`` (BatchNorm needs 2+ objects per batch), each cloud augmented anew (``loss/train`` is
the mean of these batch losses); then the loss and the gate accuracy of the training and validation
objects, unaugmented, in eval mode (``loss/train_eval``, ``accuracy/train``, ``loss/val``, ``accuracy/val``).
Repeatable on CPU:
the same data, settings and seed give identical weights (torch's CPU kernels used here are deterministic).
"""

from __future__ import annotations

import copy
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.errors import ConfigError
from ges_core.gating.clouds import AugmentConfig, augment
from ges_core.gating.data import SuccessRates, split_indices, targets
from ges_core.gating.loss import gate_accuracy, kl_loss

__all__ = ["GateData", "TrainConfig", "TrainResult", "train_model"]

log = logging.getLogger(__name__)


class TrainConfig(ConfigModel):
    """How ``ges train-gate`` trains a gate (the ``train`` section of its config)."""

    epochs: int = Field(60, ge=1, description="passes over the training objects")
    batch_size: int = Field(16, ge=2, description="objects per batch (2+: BatchNorm needs a batch statistic)")
    lr: float = Field(1e-3, gt=0, description="Adam learning rate at the start; cosine decay to 1 % at the end")
    weight_decay: float = Field(1e-4, ge=0, description="Adam L2 weight decay")
    val_fraction: float = Field(0.2, ge=0, lt=1, description="fraction of the kept objects held out for validation")
    seed: int = Field(0, description="seed of the weights, the split, the batch order and the augmentation")
    all_failed: Literal["drop", "uniform"] = Field(
        "drop", description="objects where every expert failed: left out (drop) or a uniform target"
    )
    keep: Literal["best_val", "last"] = Field(
        "best_val", description="weights kept at the end: lowest validation loss (last if no validation) or last"
    )
    augment: AugmentConfig = Field(default_factory=AugmentConfig, description="augmentation of the training clouds")


@dataclass(frozen=True)
class GateData:
    """Success rates with each object's cloud. clouds: (n_objects, n_points, 3) float32, object frame, metres,
    row i the cloud of ``rates.object_ids[i]``."""

    rates: SuccessRates
    clouds: torch.Tensor

    def __post_init__(self) -> None:
        if self.clouds.ndim != 3 or self.clouds.shape[0] != len(self.rates.object_ids) or self.clouds.shape[2] != 3:
            raise ConfigError(
                f"gate data: clouds have shape {tuple(self.clouds.shape)}, expected "
                f"({len(self.rates.object_ids)}, points, 3) for the {len(self.rates.object_ids)} objects of the rates"
            )


@dataclass
class TrainResult:
    """What a training run leaves besides the weights."""

    train_ids: list[str]
    val_ids: list[str]
    dropped_ids: list[str]
    """Objects left out because every expert failed (all_failed = drop)."""
    history: list[dict[str, float]] = field(default_factory=list)
    """Per epoch: epoch, lr, loss/train (mean over the epoch's batches, train mode, augmented: the objective),
    loss/train_eval, accuracy/train, loss/val, accuracy/val (eval mode, unaugmented; val NaN without a split)."""
    kept_epoch: int = 0

    def summary(self) -> dict:
        """The kept epoch's figures and the split sizes (JSON-friendly)."""
        row = self.history[self.kept_epoch - 1] if self.history else {}
        return {
            **row,
            "n_train": len(self.train_ids),
            "n_val": len(self.val_ids),
            "n_dropped": len(self.dropped_ids),
        }


def train_model(
    model: torch.nn.Module,
    data: GateData,
    config: TrainConfig,
    *,
    log_dir: str | Path | None = None,
    on_epoch: Callable[[int, TrainResult], None] | None = None,
) -> TrainResult:
    """Train ``model`` (clouds (B, N, 3) in the gate's input units -> logits (B, k)) in place.

    ``data.clouds`` must already be in the model's input units. ``log_dir``: TensorBoard event files
    there. ``on_epoch(epoch, result)`` after each epoch (checkpoints). Returns the split and the curves;
    the model ends with the weights ``config.keep`` names.
    """
    kept, p = targets(data.rates, config.all_failed)
    train_rows, val_rows = (kept[i] for i in split_indices(len(kept), config.val_fraction, config.seed))
    if len(train_rows) < 2:
        raise ConfigError(
            f"gate training needs 2+ training objects, has {len(train_rows)} (of {len(data.rates.object_ids)}, "
            f"{len(data.rates.object_ids) - len(kept)} left out because every expert failed); give more objects"
        )
    target = torch.zeros(len(data.rates.object_ids), p.shape[1], dtype=torch.float32)
    target[torch.from_numpy(kept)] = torch.from_numpy(p).float()
    ids = data.rates.object_ids
    result = TrainResult(
        [ids[i] for i in train_rows],
        [ids[i] for i in val_rows],
        [ids[i] for i in sorted(set(range(len(ids))) - set(kept))],
    )
    gen = torch.Generator().manual_seed(config.seed)
    optim = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    writer = _writer(log_dir)
    best, best_loss = None, math.inf
    try:
        for epoch in range(1, config.epochs + 1):
            lr = _cosine_lr(config, epoch)
            for group in optim.param_groups:
                group["lr"] = lr
            row = {
                "epoch": epoch,
                "lr": lr,
                "loss/train": _epoch(model, optim, data.clouds, target, train_rows, config, gen),
            }
            row.update(_scores(model, data, target, train_rows, "train_eval"))
            row["accuracy/train"] = row.pop("accuracy/train_eval")
            row.update(_scores(model, data, target, val_rows, "val"))
            result.history.append(row)
            _log(writer, row)
            watched = row["loss/val"] if len(val_rows) else row["loss/train"]
            if config.keep == "last" or watched < best_loss:
                best, best_loss, result.kept_epoch = copy.deepcopy(model.state_dict()), watched, epoch
            if on_epoch is not None:
                on_epoch(epoch, result)
    finally:
        if writer is not None:
            writer.close()
    if best is None:
        raise ConfigError(
            f"gate training diverged: the {'validation' if len(val_rows) else 'training'} loss was never finite; "
            "lower train.lr or check the clouds"
        )
    model.load_state_dict(best)
    model.eval()
    return result


def _cosine_lr(config: TrainConfig, epoch: int) -> float:
    """Cosine decay from lr (epoch 1) to lr / 100 (last epoch): a smooth end without a schedule to tune."""
    frac = (epoch - 1) / max(config.epochs - 1, 1)
    return config.lr * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * frac)))


def _batches(rows: np.ndarray, batch_size: int, gen: torch.Generator) -> list[np.ndarray]:
    """``rows`` in a seeded order cut into len // batch_size batches (sizes batch_size .. 2 batch_size - 1)."""
    order = rows[torch.randperm(len(rows), generator=gen).numpy()]
    return np.array_split(order, max(1, len(rows) // batch_size))


def _epoch(model, optim, clouds, target, rows, config: TrainConfig, gen: torch.Generator) -> float:
    """One pass over ``rows``; returns the mean of the batches' losses (train mode, augmented: what is minimized)."""
    model.train()
    total = 0.0
    for batch in _batches(rows, config.batch_size, gen):
        idx = torch.from_numpy(batch)
        loss = kl_loss(model(augment(clouds[idx], config.augment, gen)), target[idx])
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        total += float(loss.detach()) * len(batch)
    return total / len(rows)


def _scores(model, data: GateData, target, rows: np.ndarray, split: str) -> dict[str, float]:
    """Loss and gate accuracy of the objects ``rows`` (unaugmented, eval mode); NaN when there are none."""
    if len(rows) == 0:
        return {f"loss/{split}": float("nan"), f"accuracy/{split}": float("nan")}
    model.eval()
    idx = torch.from_numpy(rows)
    with torch.no_grad():
        logits = torch.cat([model(data.clouds[idx[i : i + 64]]) for i in range(0, len(idx), 64)])
    return {
        f"loss/{split}": float(kl_loss(logits, target[idx])),
        f"accuracy/{split}": gate_accuracy(logits, data.rates.rates[rows]),
    }


def _writer(log_dir: str | Path | None):
    if log_dir is None:
        return None
    from torch.utils.tensorboard import SummaryWriter  # imported here: tensorboard is only needed to log

    return SummaryWriter(log_dir=str(log_dir))


def _log(writer, row: dict[str, float]) -> None:
    msg = " ".join(f"{k} {v:.4g}" for k, v in row.items() if k != "epoch")
    log.info("epoch %d: %s", row["epoch"], msg)
    if writer is not None:
        for key, value in row.items():
            if key != "epoch" and not math.isnan(value):
                writer.add_scalar(key, value, row["epoch"])
