"""Training a torch gate with the paper's KL loss: seeded batches, validation split, TensorBoard curves.

One epoch: the training objects in a seeded random order, in batches of ``batch_size`` to
``2 batch_size - 1`` (BatchNorm needs 2+ objects per batch), each cloud augmented anew (``loss/train`` is
the mean of these batch losses); then the loss and the gate accuracy of the training and validation
objects, unaugmented, in eval mode (``loss/train_eval``, ``accuracy/train``, ``loss/val``, ``accuracy/val``).
Repeatable on CPU:
the same data, settings and seed give identical weights (torch's CPU kernels used here are deterministic).

Resumable: with a ``state_file``, the whole training state (weights, optimizer, the batch and augmentation
random stream, torch's global stream that dropout draws from, the best weights so far, the curves) is written
there atomically every ``state_every`` epochs and after the last; ``resume=True`` continues from it, so a run
killed and resumed ends with the same weights and curves as one that never stopped. A state written for other
data or settings is refused, naming what differs.
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
from pydantic import Field, model_validator

from ges_core.config import STORED_WHEN_SET, ConfigModel
from ges_core.errors import ArrayError, ConfigError, StorageError
from ges_core.gating.clouds import AugmentConfig, augment
from ges_core.gating.data import (
    SuccessRates,
    category_smoothed,
    fold_indices,
    normalized,
    split_indices,
    targets,
)
from ges_core.gating.loss import gate_accuracy, kl_loss
from ges_core.paths import atomic_write_bytes

__all__ = ["GateData", "TrainConfig", "TrainResult", "train_model"]

log = logging.getLogger(__name__)


class TrainConfig(ConfigModel):
    """How ``ges train-gate`` trains a gate (the ``train`` section of its config)."""

    epochs: int = Field(60, ge=1, description="passes over the training objects")
    batch_size: int = Field(16, ge=2, description="objects per batch (2+: BatchNorm needs a batch statistic)")
    lr: float = Field(1e-3, gt=0, description="Adam learning rate at the start; cosine decay to 1 % at the end")
    weight_decay: float = Field(1e-4, ge=0, description="Adam L2 weight decay")
    val_fraction: float = Field(
        0.2, ge=0, lt=1, description="fraction of the kept objects held out for validation (folds 1)"
    )
    folds: int = Field(
        1,
        ge=1,
        description="1: one gate, val_fraction of the objects held out. K >= 2: K gates, each holding out one of K "
        "seeded parts of the objects, averaged into one (ges_core.gating.folds): every object gets a score from a "
        "gate that never saw it, so the pick rule is chosen on all of them instead of one validation split",
    )
    distill: bool = Field(
        False,
        description="with folds K >= 2: after the K networks, train one more of the plugin on every kept object "
        "towards their averaged probabilities and store it as the gate (one network's inference time instead of "
        "K's; ges_core.gating.distill)",
    )
    # distill_epochs: the student learns one fixed target per object (the teacher's scores), not the K members'
    # noisy rates, and may need fewer or more passes than a member; None keeps the members' count (as before).
    distill_epochs: int | None = Field(
        None,
        ge=1,
        description="with distill: epochs of the distilled network (None: epochs, the members' count)",
        json_schema_extra=STORED_WHEN_SET,  # added after gate runs were written: stored only when set
    )
    seed: int = Field(0, description="seed of the weights, the split, the batch order and the augmentation")
    all_failed: Literal["drop", "uniform"] = Field(
        "drop", description="objects where every expert failed: left out (drop) or a uniform target"
    )
    category_smoothing: float = Field(
        0.0,
        ge=0,
        le=1,
        description="weight of the category's mean rates in each training object's target (0: the paper's, the "
        "object's own rates); the mean is over the training objects of the category, validation targets stay raw",
    )
    keep: Literal["best_val", "last"] = Field(
        "best_val", description="weights kept at the end: lowest validation loss (last if no validation) or last"
    )
    augment: AugmentConfig = Field(default_factory=AugmentConfig, description="augmentation of the training clouds")

    @model_validator(mode="after")
    def _distill_needs_folds(self) -> TrainConfig:
        if self.distill and self.folds < 2:
            raise ValueError(
                f"train.distill distils the averaged networks of train.folds >= 2 into one; folds is {self.folds}: "
                "set folds (e.g. --folds 5) or leave distill off"
            )
        if self.distill_epochs is not None and not self.distill:
            raise ValueError(
                f"train.distill_epochs ({self.distill_epochs}) sets the distilled network's epochs, and distill is "
                "off: add --distill (train.distill=true) or leave distill_epochs unset"
            )
        return self

    @property
    def student_epochs(self) -> int:
        """Epochs of the distilled network: ``distill_epochs``, else ``epochs``."""
        return self.epochs if self.distill_epochs is None else self.distill_epochs


@dataclass(frozen=True)
class GateData:
    """Success rates with each object's cloud. clouds: (n_objects, n_points, 3) float32, object frame, metres,
    row i the cloud of ``rates.object_ids[i]``."""

    rates: SuccessRates
    clouds: torch.Tensor
    categories: tuple[str, ...] | None = None
    """(n_objects,) each object's category (the matrix's), for ``TrainConfig.category_smoothing``; None: unknown."""

    def __post_init__(self) -> None:
        if self.clouds.ndim != 3 or self.clouds.shape[0] != len(self.rates.object_ids) or self.clouds.shape[2] != 3:
            raise ConfigError(
                f"gate data: clouds have shape {tuple(self.clouds.shape)}, expected "
                f"({len(self.rates.object_ids)}, points, 3) for the {len(self.rates.object_ids)} objects of the rates"
            )
        if self.categories is not None and len(self.categories) != len(self.rates.object_ids):
            raise ConfigError(
                f"gate data: {len(self.categories)} categories for the {len(self.rates.object_ids)} objects of the "
                "rates"
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
    state_file: str | Path | None = None,
    state_every: int = 5,
    resume: bool = False,
    fold: int | None = None,
    soft_targets: torch.Tensor | None = None,
) -> TrainResult:
    """Train ``model`` (clouds (B, N, 3) in the gate's input units -> logits (B, k)) in place.

    ``data.clouds`` must already be in the model's input units. ``log_dir``: TensorBoard event files
    there. ``on_epoch(epoch, result)`` after each epoch (checkpoints). ``state_file``: the training state
    written there every ``state_every`` epochs and after the last (module docs); ``resume``: continue from
    it (a missing file starts from scratch, saying so). ``fold``: with ``config.folds`` >= 2, which fold of the
    kept objects is held out (:func:`~ges_core.gating.data.fold_indices`; ``val_fraction`` unused).
    ``soft_targets``: (n_objects, k) probabilities (rows sum to 1) to fit instead of the normalized rates, e.g. a
    teacher gate's (:mod:`~ges_core.gating.distill`); the objects kept and the accuracies still follow the rates.
    Returns the split and the curves; the model ends with the weights ``config.keep`` names.
    """
    kept, p = targets(data.rates, config.all_failed)
    if soft_targets is not None:
        p = _checked_soft_targets(soft_targets, data)[kept]
    train_rows, val_rows = (kept[i] for i in _split(len(kept), config, fold))
    if len(train_rows) < 2:
        raise ConfigError(
            f"gate training needs 2+ training objects, has {len(train_rows)} (of {len(data.rates.object_ids)}, "
            f"{len(data.rates.object_ids) - len(kept)} left out because every expert failed); give more objects"
        )
    target = torch.zeros(len(data.rates.object_ids), p.shape[1], dtype=torch.float32)
    target[torch.from_numpy(kept)] = torch.as_tensor(p).float()
    if config.category_smoothing and soft_targets is None:
        target[torch.from_numpy(train_rows)] = torch.from_numpy(_smoothed_targets(data, train_rows, config)).float()
    ids = data.rates.object_ids
    result = TrainResult(
        [ids[i] for i in train_rows],
        [ids[i] for i in val_rows],
        [ids[i] for i in sorted(set(range(len(ids))) - set(kept))],
    )
    gen = torch.Generator().manual_seed(config.seed)
    optim = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    best, best_loss, done = None, math.inf, 0
    identity = _identity(config, data, train_rows, val_rows, soft_targets)
    if resume and state_file is not None:
        state = _read_state(Path(state_file), identity)
        if state is not None:
            model.load_state_dict(state["model"])
            optim.load_state_dict(state["optim"])
            gen.set_state(state["generator"])
            torch.set_rng_state(state["torch_rng"])  # dropout draws from torch's global stream
            best, best_loss, done = state["best"], state["best_loss"], state["epoch"]
            result.history, result.kept_epoch = list(state["history"]), state["kept_epoch"]
            log.info("resuming gate training after epoch %d of %d (%s)", done, config.epochs, state_file)
    writer = _writer(log_dir, purge_step=done + 1 if done else None)
    try:
        for epoch in range(done + 1, config.epochs + 1):
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
            if state_file is not None and (epoch % state_every == 0 or epoch == config.epochs):
                _write_state(Path(state_file), identity, epoch, model, optim, gen, best, best_loss, result)
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


def _split(n: int, config: TrainConfig, fold: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(train, validation) positions among the ``n`` kept objects: a fold of ``config.folds``, or val_fraction."""
    if config.folds == 1:
        if fold is not None:
            raise ConfigError(f"fold {fold} given but train.folds is 1; set train.folds to the number of folds")
        return split_indices(n, config.val_fraction, config.seed)
    if fold is None:
        raise ConfigError(
            f"train.folds = {config.folds} trains one gate per fold: use ges train-gate (ges_core.gating.folds), "
            "or pass the fold to train"
        )
    return fold_indices(n, config.folds, fold, config.seed)


def _checked_soft_targets(soft: torch.Tensor, data: GateData) -> torch.Tensor:
    """``soft`` as float64 if it is (n_objects, k) finite probabilities with rows summing to 1, else an ArrayError."""
    soft = torch.as_tensor(soft, dtype=torch.float64)
    shape = (len(data.rates.object_ids), len(data.rates.experts))
    if tuple(soft.shape) != shape:
        raise ArrayError(f"soft targets have shape {tuple(soft.shape)}, expected (objects, experts) = {shape}")
    if not torch.isfinite(soft).all() or (soft < 0).any() or not torch.allclose(soft.sum(1), torch.ones(1).double()):
        raise ArrayError("soft targets must be finite probabilities whose rows sum to 1")
    return soft


def _smoothed_targets(data: GateData, rows: np.ndarray, config: TrainConfig) -> np.ndarray:
    """(len(rows), k) targets of the training ``rows`` from their category-smoothed rates, normalized to sum to 1."""
    if data.categories is None:
        raise ConfigError(
            "train.category_smoothing needs each object's category: give the gate data its categories "
            "(ges train-gate reads them from the matrix)"
        )
    return normalized(category_smoothed(data.rates.rates, data.categories, rows, config.category_smoothing))


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


STATE_FORMAT = "ges-gate-train-state"


def _identity(
    config: TrainConfig, data: GateData, train_rows: np.ndarray, val_rows: np.ndarray, soft_targets=None
) -> dict:
    """What a resumed run must share with the one that wrote the state: settings (the epoch count aside: a
    finished run may be extended), objects and their rates, experts, the split, the input clouds, the soft targets
    when given."""
    unset = set() if config.category_smoothing else {"category_smoothing"}  # states written before these existed
    unset |= set() if config.folds > 1 else {"folds"}
    unset |= {"distill", "distill_epochs"}  # what follows the folds' networks, not how one trains
    identity = {
        "config": config.model_dump(mode="json", exclude={"epochs"} | unset),
        "object_ids": list(data.rates.object_ids),
        "experts": list(data.rates.experts),
        "rates": np.asarray(data.rates.rates, dtype=np.float64).round(12).tolist(),
        "train_rows": [int(i) for i in train_rows],
        "val_rows": [int(i) for i in val_rows],
        "clouds": [list(data.clouds.shape), float(data.clouds.double().sum()), float(data.clouds.double().abs().sum())],
    }
    if config.category_smoothing:
        identity["categories"] = list(data.categories or ())
    if soft_targets is not None:
        identity["soft_targets"] = np.asarray(soft_targets, dtype=np.float64).round(6).tolist()
    return identity


def _write_state(path: Path, identity: dict, epoch: int, model, optim, gen, best, best_loss, result) -> None:
    import io

    buffer = io.BytesIO()
    torch.save(
        {
            "format": STATE_FORMAT,
            "identity": identity,
            "epoch": epoch,
            "model": model.state_dict(),
            "optim": optim.state_dict(),
            "generator": gen.get_state(),
            "torch_rng": torch.get_rng_state(),
            "best": best,
            "best_loss": best_loss,
            "kept_epoch": result.kept_epoch,
            "history": result.history,
        },
        buffer,
    )
    atomic_write_bytes(path, buffer.getvalue())


def _read_state(path: Path, identity: dict) -> dict | None:
    """The state at ``path`` if it was written for ``identity``; None (logged) when there is none; a ConfigError
    naming what differs, or a StorageError for a file that is not a training state."""
    if not path.is_file():
        log.warning("no training state at %s: training from the first epoch", path)
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises several types for a corrupt file
        raise StorageError(f"{path} is not a readable gate training state ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
        raise StorageError(f"{path} is not a gate training state (no format '{STATE_FORMAT}')")
    differ = [k for k in identity if state["identity"].get(k) != identity[k]]
    if differ:
        raise ConfigError(
            f"{path} was written by a gate training run with other {', '.join(differ)}; resume with the same "
            "matrix, settings and seed, or train without --resume (or into another --out) to start over"
        )
    return state


def _writer(log_dir: str | Path | None, purge_step: int | None = None):
    """TensorBoard writer in ``log_dir`` (None: no logging); ``purge_step``: a resumed run's first epoch, so the
    events a killed run wrote after its last saved state are dropped instead of doubled."""
    if log_dir is None:
        return None
    from torch.utils.tensorboard import SummaryWriter  # imported here: tensorboard is only needed to log

    return SummaryWriter(log_dir=str(log_dir), purge_step=purge_step)


def _log(writer, row: dict[str, float]) -> None:
    msg = " ".join(f"{k} {v:.4g}" for k, v in row.items() if k != "epoch")
    log.info("epoch %d: %s", row["epoch"], msg)
    if writer is not None:
        for key, value in row.items():
            if key != "epoch" and not math.isnan(value):
                writer.add_scalar(key, value, row["epoch"])
