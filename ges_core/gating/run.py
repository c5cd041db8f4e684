"""``ges train-gate``'s pipeline: matrix -> rates and clouds -> fitted gate -> checkpoint, curves, summary.

A killed run continues with ``resume`` (``ges train-gate --resume``) from OUT/train_state.pt, written with each
checkpoint: it ends with the weights and curves of a run that never stopped.

Objects: the matrix's ``split`` rows (train by default) are the gate's data, of which ``val_fraction``
is held out for validation; the matrix's other splits are scored too (unseen objects, unseen
categories), never trained on. Clouds are sampled once per (object, size, seed) and cached in
OUT/clouds-<n>-<seed>.pt (an object set or library change is detected by the ids it holds).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from pydantic import Field

from ges_core.config import ConfigModel, apply_overrides, parse_model, read_yaml
from ges_core.errors import ConfigError
from ges_core.experts.compare import column_list
from ges_core.gating.clouds import library_clouds
from ges_core.gating.loss import gate_accuracy
from ges_core.gating.sources import MatrixRates, load_rates
from ges_core.gating.train import GateData, TrainConfig, TrainResult
from ges_core.paths import atomic_write_bytes, atomic_write_text

__all__ = ["GateRunSummary", "TrainGateConfig", "config_from_args", "train_gate_run"]

log = logging.getLogger(__name__)

SPLITS = ("train", "unseen_object", "unseen_category")


class TrainGateConfig(ConfigModel):
    """Everything ``ges train-gate`` does, as one YAML (``--config``) with ``-o key=value`` overrides."""

    matrix: Path = Field(..., description="success matrix JSON (ges eval-experts)")
    pool: list[Path] = Field(
        default_factory=list,
        description="more matrices of the same objects and experts under other evaluation seeds, whose episodes "
        "are added to the matrix's before the targets are taken (smoother targets)",
    )
    dataset: Path | None = Field(
        None, description="Stage 1 dataset whose library holds the objects (None: the matrix's)"
    )
    out: Path | None = Field(None, description="run folder (None: <matrix folder>/gate-<gate>)")
    gate: str = Field("curvenet", description="gate plugin name")
    settings: dict[str, Any] = Field(
        default_factory=dict, description="the gate plugin's settings (over registry.yaml's)"
    )
    experts: list[str] | None = Field(None, description="expert columns to choose among (None: all but the baseline)")
    protocol: str = Field("paper", description="success protocol of the matrix whose rates are the targets")
    split: str = Field("train", description="matrix split trained on (its val_fraction held out)")
    cloud_seed: int = Field(0, description="seed of the surface samples the clouds are drawn from")
    checkpoint_every: int = Field(5, ge=1, description="epochs between checkpoints (and one at the end)")
    train: TrainConfig = Field(default_factory=TrainConfig, description="training settings")


def config_from_args(args: argparse.Namespace) -> TrainGateConfig:
    """The config of ``ges train-gate``'s arguments: YAML, then the named options, then ``-o`` overrides."""
    data = read_yaml(args.config) if args.config else {}
    data["matrix"] = str(args.matrix[0])
    if len(args.matrix) > 1:
        data["pool"] = [str(p) for p in args.matrix[1:]]
    if args.experts is not None:
        data["experts"] = column_list(args.experts)
    named = {"dataset": args.dataset, "out": args.out, "gate": args.gate}
    data.update({k: str(v) for k, v in named.items() if v is not None})
    if args.points is not None:
        data.setdefault("settings", {})["n_points"] = args.points
    train = data.setdefault("train", {})
    for key, value in (("epochs", args.epochs), ("seed", args.seed)):
        if value is not None:
            train[key] = value
    if args.no_augment:
        train.setdefault("augment", {})["enabled"] = False
    return parse_model(TrainGateConfig, apply_overrides(data, args.overrides), where="ges train-gate config")


@dataclass
class GateRunSummary:
    """What a run found: accuracy per split, where things are."""

    gate: str
    experts: tuple[str, ...]
    n_points: int
    accuracy: dict[str, float]
    """train (the fitted objects), val (held out), unseen_object, unseen_category; NaN where none."""
    counts: dict[str, int]
    kept_epoch: int
    seconds: float
    checkpoint: Path

    def table(self) -> str:
        """Markdown table of the gate accuracy per split."""
        rows = [f"| {k} | {self.counts.get(k, 0)} | {_pct(v)} |" for k, v in self.accuracy.items()]
        head = [
            f"gate {self.gate} ({self.n_points} points) over experts {', '.join(self.experts)}; "
            f"kept epoch {self.kept_epoch}; {self.seconds:.1f} s; checkpoint {self.checkpoint}",
            "",
            "| objects | n | gate accuracy (pick among the best) |",
            "|---|---|---|",
        ]
        return "\n".join(head + rows)

    def to_json(self) -> dict:
        return {**self.__dict__, "experts": list(self.experts), "checkpoint": str(self.checkpoint)}


def _pct(v: float) -> str:
    return "-" if v != v else f"{100 * v:.1f} %"


def train_gate_run(
    config: TrainGateConfig, registry=None, *, resume: bool = False, progress: bool = False
) -> GateRunSummary:
    """Train the gate ``config`` describes; write OUT/gate.pt, train_state.pt, tb/, history.json, summary.json.
    ``resume``: continue from OUT/train_state.pt (a state of other data or settings is a ConfigError).
    ``progress``: a bar over the epochs with the last epoch's losses."""
    from tqdm import tqdm

    start = time.perf_counter()
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    matrix = load_rates(config.matrix, config.protocol, columns=config.experts, pool=config.pool)
    out = config.out or Path(config.matrix).parent / f"gate-{config.gate}"
    gate = _build_gate(registry, config)
    n = gate.settings.n_points
    library = _library(config, matrix)
    data = _split_data(matrix, config.split, library, n, config.cloud_seed, out)
    checkpoint = out / "gate.pt"

    bar = tqdm(total=config.train.epochs, desc=f"gate {config.gate}", unit="epoch", disable=not progress)

    def on_epoch(epoch: int, result: TrainResult) -> None:
        if epoch % config.checkpoint_every == 0:
            gate.save(checkpoint)
        row = result.history[-1]
        bar.update(epoch - bar.n)  # a resumed run's first call moves the bar to where the state left off
        bar.set_postfix({k.replace("loss/", "loss "): f"{row[k]:.4g}" for k in ("loss/train", "loss/val") if k in row})

    with bar:
        result = gate.fit(
            data,
            config.train,
            log_dir=out / "tb",
            on_epoch=on_epoch,
            state_file=out / "train_state.pt",
            state_every=config.checkpoint_every,
            resume=resume,
        )
    gate.save(checkpoint)
    atomic_write_text(out / "history.json", json.dumps(result.history, indent=1) + "\n")
    accuracy, counts = _accuracies(result, gate, matrix, library, n, config, out)
    summary = GateRunSummary(
        config.gate, gate.experts, n, accuracy, counts, result.kept_epoch, time.perf_counter() - start, checkpoint
    )
    written = {**summary.to_json(), "config": config.model_dump(mode="json")}
    written["matrix"] = str(Path(config.matrix).resolve())  # where `ges evaluate --gate` finds it from any folder
    atomic_write_text(out / "summary.json", json.dumps(written, indent=1) + "\n")
    return summary


def _build_gate(registry, config: TrainGateConfig):
    spec = registry.spec("gate", config.gate)
    return spec.load()(**{**registry.settings("gate", spec.name), **config.settings})


def _library(config: TrainGateConfig, matrix: MatrixRates):
    from ges_core.dataset import open_dataset
    from ges_core.env.grasp_source import library_for

    dataset = config.dataset or (Path(matrix.dataset) if matrix.dataset else None)
    if dataset is None:
        raise ConfigError(
            f"{config.matrix} does not name its dataset; give --dataset (the Stage 1 dataset it evaluated)"
        )
    return library_for(open_dataset(dataset))


def _split_data(matrix: MatrixRates, split: str, library, n: int, seed: int, out: Path) -> GateData:
    rates = matrix.split(split)
    if len(rates.object_ids) < 2:
        raise ConfigError(
            f"the matrix has {len(rates.object_ids)} evaluated object(s) in split '{split}'; a gate needs 2+"
        )
    return GateData(rates, _cached_clouds(library, rates.object_ids, n, seed, out))


def _cached_clouds(library, ids: tuple[str, ...], n: int, seed: int, out: Path) -> torch.Tensor:
    """Clouds of ``ids`` from OUT/clouds-<n>-<seed>.pt when it holds them, else sampled and added to it."""
    path = out / f"clouds-{n}-{seed}.pt"
    cache: dict[str, torch.Tensor] = torch.load(path, weights_only=True) if path.is_file() else {}
    missing = [i for i in ids if i not in cache]
    if missing:
        log.info("sampling %d cloud(s) of %d points", len(missing), n)
        cache.update(zip(missing, library_clouds(library, missing, n, seed=seed), strict=True))
        import io

        buffer = io.BytesIO()
        torch.save(cache, buffer)
        atomic_write_bytes(path, buffer.getvalue())
    return torch.stack([cache[i] for i in ids])


def _accuracies(result: TrainResult, gate, matrix: MatrixRates, library, n: int, config: TrainGateConfig, out: Path):
    """Gate accuracy on the fitted, held-out and unseen-split objects (objects where every expert failed left out)."""
    acc = {"train": result.summary().get("accuracy/train", float("nan")),
           "val": result.summary().get("accuracy/val", float("nan"))}  # fmt: skip
    counts = {"train": len(result.train_ids), "val": len(result.val_ids)}
    for split in SPLITS[1:]:
        rates = matrix.split(split)
        keep = [i for i, r in enumerate(rates.rates) if r.max() > 0]
        counts[split] = len(keep)
        if not keep:
            acc[split] = float("nan")
            continue
        sub = rates.subset(keep)
        probs = gate.predict(_cached_clouds(library, sub.object_ids, n, config.cloud_seed, out), sub.object_ids)
        acc[split] = gate_accuracy(probs, sub.rates)
    return acc, counts
