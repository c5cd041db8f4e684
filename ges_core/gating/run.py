"""``ges train-gate``'s pipeline: matrix -> rates and clouds -> fitted gate -> checkpoint, curves, summary.

A killed run continues with ``resume`` (``ges train-gate --resume``) from OUT/train_state.pt (a folds run: each
OUT/fold-f/train_state.pt), written with each checkpoint: it ends with the weights and curves of a run that never
stopped.

Objects: the matrix's ``split`` rows (train by default) are the gate's data, of which ``val_fraction`` is held out
for validation (or, with ``train.folds`` K >= 2, each of K folds in turn, one network per fold, averaged:
:mod:`ges_core.gating.folds`; "val" is then every kept object scored by the network that never saw it; with
``train.distill`` the average is then distilled into one network, :mod:`ges_core.gating.distill`); the
matrix's other splits are scored too (unseen objects, unseen categories), never trained on. Clouds are sampled once
per (object, size, seed) and cached in OUT/clouds-<n>-<seed>.pt (an object set or library change is detected by the
ids it holds).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel, apply_overrides, parse_model, read_yaml
from ges_core.errors import ConfigError
from ges_core.experts.compare import column_list
from ges_core.gating.checkpoint import write_pick_rule
from ges_core.gating.clouds import library_clouds
from ges_core.gating.data import best_experts
from ges_core.gating.distill import agreement_of, distill
from ges_core.gating.fallback import ARGMAX, PickRule, fit_pick_rule
from ges_core.gating.folds import FoldsResult, train_folds
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
    pick: Literal["fallback", "argmax"] = Field(
        "fallback",
        description="how the gate's distribution becomes one expert (stored in the checkpoint): fallback, the best "
        "single training expert unless the gate leads it by a margin chosen on the validation objects "
        "(ges_core.gating.fallback); argmax, the paper's rule",
    )
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
    for key, value in (("epochs", args.epochs), ("seed", args.seed), ("folds", args.folds)):
        if value is not None:
            train[key] = value
    if args.distill:
        train["distill"] = True
    if args.distill_epochs is not None:
        train["distill_epochs"] = args.distill_epochs
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
    """train (the fitted objects), val (held out), unseen_object, unseen_category; NaN where none. The paper's gate
    accuracy: the argmax is one of the object's best experts. With folds: train, the averaged gate on every kept
    object (each seen by all members but one); val, each kept object scored by the member that held it out."""
    counts: dict[str, int]
    kept_epoch: int | tuple[int, ...]
    """The epoch whose weights were kept; with folds, one per member."""
    seconds: float
    checkpoint: Path
    pick: PickRule = ARGMAX
    """The rule stored in the checkpoint (config ``pick``)."""
    picked: dict[str, dict[str, float]] | None = None
    """Per split as :attr:`accuracy`: ``accuracy`` (the rule's pick is one of the best), ``success`` (mean success
    rate of the rule's picks in the matrix), ``argmax_success`` and ``fallback_success`` (of the argmax's picks and
    of the fallback expert alone); None for the argmax rule."""
    distilled: dict[str, dict[str, float]] | None = None
    """With ``train.distill``: per split (train, unseen_object, unseen_category), the fraction of objects where the
    distilled network picks what the averaged networks (OUT/averaged.pt) pick: ``pick`` by the stored rule,
    ``argmax`` by the argmax; None otherwise."""

    def table(self) -> str:
        """Markdown table of the gate accuracy per split (and, with a fallback rule, what the rule picks)."""
        kept = (
            f"kept epoch {self.kept_epoch}"
            if isinstance(self.kept_epoch, int)
            else f"{len(self.kept_epoch)} folds averaged (kept epochs {', '.join(map(str, self.kept_epoch))}; val: "
            "each object scored by the network that held it out)"
        )
        head = [
            f"gate {self.gate} ({self.n_points} points) over experts {', '.join(self.experts)}; "
            f"{kept}; {self.seconds:.1f} s; checkpoint {self.checkpoint}",
            f"pick: {self.pick.describe()}" + (f" ({self.pick.how})" if self.pick.fallback else ""),
            "",
        ]
        if self.distilled:
            agree = ", ".join(f"{k} {_pct(v['pick'])} ({_pct(v['argmax'])})" for k, v in self.distilled.items())
            head.insert(-1, f"distilled into one network (the averaged one: {self.checkpoint.parent / 'averaged.pt'}); "
                            f"its pick (argmax) is the average's on: {agree}")  # fmt: skip
        if not self.picked:
            rows = [f"| {k} | {self.counts.get(k, 0)} | {_pct(v)} |" for k, v in self.accuracy.items()]
            return "\n".join(head + ["| objects | n | gate accuracy (pick among the best) |", "|---|---|---|"] + rows)
        rows = [
            f"| {k} | {self.counts.get(k, 0)} | {_pct(v)} | {_pct(self.picked[k]['accuracy'])} | "
            f"{_pct(self.picked[k]['success'])} | {_pct(self.picked[k]['argmax_success'])} | "
            f"{_pct(self.picked[k]['fallback_success'])} |"
            for k, v in self.accuracy.items()
        ]
        return "\n".join(head + [
            "| objects | n | gate accuracy (argmax among the best) | the rule's pick among the best | success of the "
            "rule's picks (matrix) | of the argmax's | of the fallback alone |",
            "|---|---|---|---|---|---|---|",
        ] + rows)  # fmt: skip

    def to_json(self) -> dict:
        return {**self.__dict__, "experts": list(self.experts), "checkpoint": str(self.checkpoint),
                "pick": self.pick.to_json()}  # fmt: skip


def _pct(v: float) -> str:
    return "-" if v != v else f"{100 * v:.1f} %"


def train_gate_run(
    config: TrainGateConfig, registry=None, *, resume: bool = False, progress: bool = False
) -> GateRunSummary:
    """Train the gate ``config`` describes; write OUT/gate.pt, train_state.pt, tb/, history.json, summary.json (with
    ``train.folds`` K: OUT/gate.pt averaging the members of OUT/fold-f/, history.json per fold; with
    ``train.distill`` too: OUT/gate.pt the distilled network of OUT/distilled/, OUT/averaged.pt the average).
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

    folds, epochs = config.train.folds, config.train.epochs
    total = folds * epochs + (config.train.student_epochs if config.train.distill else 0)
    bar = tqdm(total=total, desc=f"gate {config.gate}", unit="epoch", disable=not progress)

    def on_epoch(fold: int, epoch: int, result: TrainResult) -> None:
        if folds == 1 and epoch % config.checkpoint_every == 0:
            gate.save(checkpoint)
        row = result.history[-1]
        bar.update(fold * epochs + epoch - bar.n)  # a resumed run's first call moves the bar to where it left off
        shown = {k.replace("loss/", "loss "): f"{row[k]:.4g}" for k in ("loss/train", "loss/val") if k in row}
        where = {"fold": f"{fold + 1}/{folds}"} if fold < folds else {"network": "distilled"}
        bar.set_postfix((where if folds > 1 else {}) | shown)

    with bar:
        if folds == 1:
            result = gate.fit(
                data,
                config.train,
                log_dir=out / "tb",
                on_epoch=lambda epoch, result: on_epoch(0, epoch, result),
                state_file=out / "train_state.pt",
                state_every=config.checkpoint_every,
                resume=resume,
            )
        else:
            folded = train_folds(lambda: _build_gate(registry, config), data, config.train, out, resume=resume,
                                 state_every=config.checkpoint_every, on_epoch=on_epoch)  # fmt: skip
            gate = teacher = folded.gate
            if config.train.distill:
                gate, distilled = distill(lambda: _build_gate(registry, config), teacher, data, config.train, out,
                                          resume=resume, state_every=config.checkpoint_every,
                                          on_epoch=lambda epoch, result: on_epoch(folds, epoch, result))  # fmt: skip
    gate.save(checkpoint)
    if folds == 1:
        atomic_write_text(out / "history.json", json.dumps(result.history, indent=1) + "\n")
        probs = _split_probs(result, gate, matrix, library, n, config, out)
        accuracy, counts = _accuracies(result, probs)
        kept_epoch: int | tuple[int, ...] = result.kept_epoch
    else:
        histories = {f"fold-{f}": r.history for f, r in enumerate(folded.results)}
        if config.train.distill:
            histories["distilled"] = distilled.history
        atomic_write_text(out / "history.json", json.dumps(histories, indent=1) + "\n")
        probs = _fold_probs(folded, gate, matrix, library, n, config, out)
        accuracy, counts = _accuracies(None, probs)
        kept_epoch = tuple(r.kept_epoch for r in folded.results)
    rule = ARGMAX if config.pick == "argmax" else _fit_rule(gate.experts, probs)
    write_pick_rule(checkpoint, rule)
    agreement = None
    if config.train.distill:  # the averaged networks, with the same rule, for comparison
        taught = _fold_probs(folded, teacher, matrix, library, n, config, out)
        agreement = {k: agreement_of(rule, gate.experts, probs[k][0], taught[k][0]) for k in ("train", *SPLITS[1:])}
        teacher.save(out / "averaged.pt")
        write_pick_rule(out / "averaged.pt", rule)
    summary = GateRunSummary(
        config.gate,
        gate.experts,
        n,
        accuracy,
        counts,
        kept_epoch,
        time.perf_counter() - start,
        checkpoint,
        rule,
        None if rule.fallback is None else _picked(rule, gate.experts, probs),
        agreement,
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
    return GateData(rates, _cached_clouds(library, rates.object_ids, n, seed, out), matrix.split_categories(split))


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


def _split_probs(
    result: TrainResult, gate, matrix: MatrixRates, library, n: int, config: TrainGateConfig, out: Path
) -> dict[str, tuple]:
    """Per split (train: the fitted objects, val: held out, and the matrix's unseen splits): (the gate's scores
    (m, k), the objects' rates (m, k)) over the objects where some expert succeeded (as training counts them)."""
    fitted = matrix.split(config.split)
    index = {oid: i for i, oid in enumerate(fitted.object_ids)}
    parts = {name: fitted.subset([index[i] for i in ids]) for name, ids in (("train", result.train_ids),
                                                                            ("val", result.val_ids))}  # fmt: skip
    return {name: _predicted(gate, sub, library, n, config, out) for name, sub in (parts | _unseen(matrix)).items()}


def _fold_probs(
    folded: FoldsResult, gate, matrix: MatrixRates, library, n: int, config: TrainGateConfig, out: Path
) -> dict[str, tuple]:
    """As :func:`_split_probs` for a folds run: train, the averaged gate on every kept object; val, the same objects'
    out-of-fold scores (each from the member that held it out); the unseen splits by the averaged gate."""
    fitted = matrix.split(config.split)
    kept = fitted.subset([i for i, oid in enumerate(fitted.object_ids) if oid in folded.out_of_fold])
    oof = torch.stack([folded.out_of_fold[oid] for oid in kept.object_ids])
    probs = {name: _predicted(gate, sub, library, n, config, out) for name, sub in ({"train": kept} |
                                                                                 _unseen(matrix)).items()}  # fmt: skip
    return {"train": probs.pop("train"), "val": (oof, kept.rates)} | probs


def _unseen(matrix: MatrixRates) -> dict:
    """The matrix's unseen splits, each without the objects where every expert failed (as training drops them)."""
    out = {}
    for split in SPLITS[1:]:
        rates = matrix.split(split)
        out[split] = rates.subset([i for i, r in enumerate(rates.rates) if r.max() > 0])
    return out


def _predicted(gate, sub, library, n: int, config: TrainGateConfig, out: Path) -> tuple:
    """(the gate's scores (m, k), the rates (m, k)) of the objects of ``sub`` (SuccessRates)."""
    if not sub.object_ids:
        return torch.zeros(0, len(gate.experts)), sub.rates  # rates: (0, k)
    clouds = _cached_clouds(library, sub.object_ids, n, config.cloud_seed, out)
    with torch.no_grad():
        return gate.predict(clouds, sub.object_ids), sub.rates


def _fit_rule(experts, probs: dict[str, tuple]) -> PickRule:
    """The fallback rule of :func:`~ges_core.gating.fallback.fit_pick_rule` on the fitted and held-out objects."""
    return fit_pick_rule(experts, probs["train"][1], *probs["val"])


def _accuracies(result: TrainResult | None, probs: dict[str, tuple]):
    """Gate accuracy on the fitted, held-out and unseen-split objects (objects where every expert failed left out);
    train and val as training measured them (the kept epoch), or (``result`` None: a folds run) from ``probs``."""
    acc, counts = {}, {}
    if result is not None:
        acc = {"train": result.summary().get("accuracy/train", float("nan")),
               "val": result.summary().get("accuracy/val", float("nan"))}  # fmt: skip
        counts = {"train": len(result.train_ids), "val": len(result.val_ids)}
    for split in SPLITS[1:] if result is not None else ("train", "val", *SPLITS[1:]):
        p, rates = probs[split]
        counts[split] = len(rates)
        acc[split] = gate_accuracy(p, rates) if len(rates) else float("nan")
    return acc, counts


def _picked(rule: PickRule, experts, probs: dict[str, tuple]) -> dict[str, dict[str, float]]:
    """Per split: what ``rule`` picks against the argmax and the fallback alone (:attr:`GateRunSummary.picked`)."""
    nan = float("nan")
    out = {}
    for name, (p, rates) in probs.items():
        if not len(rates):
            out[name] = {"accuracy": nan, "success": nan, "argmax_success": nan, "fallback_success": nan}
            continue
        rows = np.arange(len(rates))
        pick, top = rule.choose(p, experts), np.asarray(p.argmax(dim=1))
        best = best_experts(rates)
        out[name] = {
            "accuracy": float(best[rows, pick].mean()),
            "success": float(rates[rows, pick].mean()),
            "argmax_success": float(rates[rows, top].mean()),
            "fallback_success": float(rates[:, rule.column(experts)].mean()),
        }
    return out
