"""Gate checkpoints: one torch file naming the gate plugin, its settings and the experts it serves.

Layout (a dict, readable with ``torch.load(path, weights_only=True)``)::

    format: "ges-gate", version: 1
    gate: plugin name ("curvenet", "pointnet2", "centroid")
    experts: [expert names], the order of the gate's output columns
    settings: the plugin's settings (JSON-like)
    state: tensors (torch state_dict, or the centroid gate's centres)
    members: optional, how many networks a torch gate averages (absent: 1; ``train.folds`` K writes K, the state
             then holding ``members.0.`` .. ``members.K-1.``: ges_core.gating.torch_gate.MeanOfMembers)
    train: {config, summary, train_ids, val_ids, dropped_ids} or {} for an untrained gate
    pick: optional, the rule that turns the distribution into one expert (ges_core.gating.fallback.PickRule:
          {fallback, margin, how}); absent: the paper's argmax. ``ges train-gate`` adds it after training.

Written atomically: a reader or a killed run never sees half a file.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import torch

from ges_core.errors import ConfigError, StorageError
from ges_core.gating.fallback import PickRule
from ges_core.paths import atomic_write_bytes

__all__ = ["FORMAT", "VERSION", "load_gate", "read_checkpoint", "read_pick_rule", "write_checkpoint", "write_pick_rule"]

FORMAT = "ges-gate"
VERSION = 1


def write_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` (the keys above, format/version added) to ``path`` atomically."""
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, **payload}, buffer)
    return atomic_write_bytes(path, buffer.getvalue(), fix="choose a writable --out path")


def read_checkpoint(path: str | Path, *, gate: str | None = None) -> dict[str, Any]:
    """The checkpoint at ``path``; StorageError if unreadable, ConfigError if it is not a gate checkpoint, or (with
    ``gate``) not one of that gate plugin."""
    path = Path(path)
    if not path.is_file():
        raise StorageError(f"gate checkpoint {path} does not exist; train one with `ges train-gate`")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises several types for a corrupt or foreign file
        raise ConfigError(f"{path} is not a readable gate checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(f"{path} is not a gate checkpoint (no format '{FORMAT}'); train one with `ges train-gate`")
    if data.get("version") != VERSION:
        raise ConfigError(f"{path}: gate checkpoint version {data.get('version')}, this ges reads {VERSION}")
    if gate is not None and data["gate"] != gate:
        raise ConfigError(f"{path} holds a '{data['gate']}' gate, not a '{gate}' one; load it with that plugin")
    return data


def load_gate(path: str | Path, registry=None, *, experts=None):
    """The gate saved at ``path``, built through the registry by the plugin name the checkpoint gives.

    ``experts``: if given, the experts it will be used with; a gate trained for others is a ConfigError
    naming both lists.
    """
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    name = read_checkpoint(path)["gate"]
    factory = registry.spec("gate", name).load()
    gate = factory.load(path)
    if experts is not None:
        gate.check_experts(experts)
    return gate


def write_pick_rule(path: str | Path, rule: PickRule) -> Path:
    """Store ``rule`` (a :class:`~ges_core.gating.fallback.PickRule`) in the gate checkpoint at ``path``, whatever
    plugin wrote it (rewritten atomically; the weights are untouched)."""
    data = read_checkpoint(path)
    data["pick"] = rule.to_json()
    return write_checkpoint(path, {k: v for k, v in data.items() if k not in ("format", "version")})


def read_pick_rule(path: str | Path) -> PickRule:
    """The :class:`~ges_core.gating.fallback.PickRule` stored in the checkpoint at ``path`` (the argmax if none)."""
    stored = read_checkpoint(path).get("pick")
    try:
        return PickRule.from_json(stored)
    except (TypeError, ValueError, AttributeError, ConfigError) as exc:
        raise ConfigError(
            f"{path}: its pick rule {stored!r} is not one ges_core.gating.fallback.PickRule can read ({exc}); "
            "retrain the gate (ges train-gate) or pass the file to ges evaluate with --gate-argmax"
        ) from exc
