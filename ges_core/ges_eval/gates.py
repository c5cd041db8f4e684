"""The gates of a GES run: which checkpoints, checked against the run's experts, and the expert each picks per object.

>>> gates = load_gates([parse_gate("runs/x/gate-curvenet/gate.pt")], registry, ["e1", "e2"])
>>> picks = pick_experts(gates[0], clouds_for(library, ids, gates[0].n_points), ids)

A gate reads each object's cloud exactly as ``ges train-gate`` fed it (:func:`ges_core.gating.library_clouds`:
``n_points`` farthest points of ``4 n_points`` seeded surface samples, object frame, metres) and picks one expert
by the rule stored in its checkpoint (:class:`~ges_core.gating.fallback.PickRule`: the argmax, or the best single
training expert unless the gate clearly prefers another); ``GateChoice(argmax=True)`` (``--gate-argmax``) takes the
paper's argmax whatever the checkpoint holds.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ges_core.errors import AssetError, ConfigError, StorageError
from ges_core.experts.choice import ExpertChoice, parse_expert
from ges_core.experts.matrix import read_matrix_json
from ges_core.gating.checkpoint import load_gate, read_checkpoint, read_pick_rule
from ges_core.gating.clouds import library_clouds
from ges_core.gating.fallback import ARGMAX, PickRule
from ges_core.paths import file_sha256

__all__ = [
    "GateChoice",
    "LoadedGate",
    "Picks",
    "clouds_for",
    "gate_experts",
    "load_gates",
    "parse_gate",
    "pick_experts",
    "training_matrix",
    "transfer_notes",
]

_LABEL = re.compile(r"^[A-Za-z0-9_.+-]+$")
"""What a gate label may hold: it is a JSON key and a table row name."""


@dataclass(frozen=True)
class GateChoice:
    """One ``--gate [LABEL=]PATH`` (or ``--gate-argmax``): the checkpoint, the row label (None: from the checkpoint)
    and whether to pick by the paper's argmax instead of the checkpoint's rule."""

    path: Path
    label: str | None = None
    argmax: bool = False


def parse_gate(text: str, *, argmax: bool = False) -> GateChoice:
    """``[LABEL=]PATH`` -> :class:`GateChoice` (an '=' before any '/' ends a label)."""
    head, eq, tail = text.partition("=")
    if eq and "/" not in head and head:
        if not _LABEL.match(head):
            raise ConfigError(f"gate '{text}': the label '{head}' may hold letters, digits and _.+- only")
        return GateChoice(Path(tail), head, argmax)
    return GateChoice(Path(text), argmax=argmax)


@dataclass(frozen=True)
class LoadedGate:
    """A gate ready to pick: its row label, plugin name, checkpoint (path and content hash), input size and the rule
    that turns its distribution into one expert."""

    label: str
    gate: object
    """The :class:`~ges_core.policy.Gate`."""
    plugin: str
    path: Path
    sha: str
    n_points: int
    rule: PickRule = ARGMAX

    def describe(self) -> dict:
        """JSON-ready identity (stored with the results); a network gate also says how many networks it runs
        (``networks``: K for ``ges train-gate --folds K``) and, distilled (``--distill``), how many it imitates."""
        out = {"gate": self.plugin, "path": str(self.path.resolve()), "sha": self.sha, "n_points": self.n_points,
               "experts": list(self.gate.experts), "pick": self.rule.to_json()}  # fmt: skip
        if (networks := getattr(self.gate, "members", None)) is not None:
            out["networks"] = networks
        if teacher := getattr(self.gate, "train_info", {}).get("distilled_from"):
            out["distilled_from_networks"] = teacher["members"]
        return out


def training_matrix(choice: GateChoice) -> Path | None:
    """The success matrix ``choice``'s gate was trained on, as ``ges train-gate`` names it in the ``summary.json``
    beside the checkpoint (``matrix``: the absolute path; older files only the path as given, ``config.matrix``);
    None when that file or the matrix is not there."""
    import json

    summary = choice.path.parent / "summary.json"
    if not summary.is_file():
        return None
    data = json.loads(summary.read_text())
    for given in (data.get("matrix"), data.get("config", {}).get("matrix")):
        if given and Path(given).is_file():
            return Path(given)
    return None


def transfer_notes(choices: Sequence[GateChoice], hand: str, sim: str) -> list[str]:
    """One line per gate whose :func:`training_matrix` was measured with another hand or simulator than ``hand`` and
    ``sim`` (the run's): its picks are then carried over from success rates of another hand or engine, which a user
    may mean (a gate trained once, used on a second hand) or not. Gates without a readable training matrix: none."""
    notes = []
    for choice in choices:
        path = training_matrix(choice)
        if path is None:
            continue
        try:
            run = read_matrix_json(path).get("run", {})
        except AssetError:
            continue
        trained = (run.get("hand", hand), run.get("sim", sim))
        other = [what for what, was, now in zip(("hand", "simulator"), trained, (hand, sim), strict=True) if was != now]
        if other:
            notes.append(
                f"gate {choice.path} was trained on the success rates of {trained[0]} in {trained[1]} (its matrix "
                f"{path}); this run is {hand} in {sim}: its picks come from another {' and '.join(other)}"
            )
    return notes


def gate_experts(choice: GateChoice, registry, matrix: dict | None) -> list[ExpertChoice]:
    """The experts ``choice``'s gate was trained for, as :class:`~ges_core.experts.choice.ExpertChoice` under the
    gate's labels, so that ``ges evaluate DATASET --gate PATH`` needs no ``--expert``.

    Each label's expert comes from ``matrix``, the gate's :func:`training_matrix` as read
    (:func:`~ges_core.experts.matrix.read_matrix_json`; None when there is none): its column identity, every
    setting. Otherwise a label that is itself an expert text (the default label, e.g. ``ppo:checkpoint=...``) is read
    as one. A label neither explains is a ConfigError saying to give ``--expert``."""
    labels = list(read_checkpoint(choice.path)["experts"])
    columns = (matrix or {}).get("experts", {})
    out = []
    for label in labels:
        if label in columns:
            out.append(ExpertChoice(label, columns[label]["name"], dict(columns[label].get("settings", {}))))
            continue
        try:
            parsed = parse_expert(label)
        except ConfigError:
            parsed = None
        if parsed is None or parsed.name not in registry.names("expert"):
            raise ConfigError(
                f"gate {choice.path} was trained for the experts {labels}; '{label}' is not an expert text and no "
                "success matrix named beside the gate (summary.json) gives it: name every expert with --expert "
                "LABEL=NAME:settings"
            )
        out.append(parsed)
    return out


def load_gates(choices: Sequence[GateChoice], registry, experts: Sequence[str]) -> list[LoadedGate]:
    """Each gate of ``choices``, checked against ``experts`` (the labels of the experts the run was given).

    A missing or foreign file is a StorageError / ConfigError naming it; a gate trained for other experts than
    ``experts`` is the gate's ConfigError naming both lists (:meth:`~ges_core.policy.Gate.check_experts`). Labels:
    the given one, else the plugin name, else (two of one plugin) ``plugin-n_points``; still equal: ConfigError.
    """
    if not choices:
        raise ConfigError("no gate given; pass --gate PATH (a gate.pt of ges train-gate), once per gate to compare")
    loaded = [_load_one(c, registry, experts) for c in choices]
    return _label(loaded, choices)


def _load_one(choice: GateChoice, registry, experts: Sequence[str]) -> LoadedGate:
    path = choice.path
    if not path.is_file():
        raise StorageError(f"--gate {path}: no such file; give the gate.pt that ges train-gate wrote (OUT/gate.pt)")
    plugin = read_checkpoint(path)["gate"]
    gate = load_gate(path, registry)
    gate.check_experts(_in_gate_order(gate.experts, experts))
    rule = ARGMAX if choice.argmax else read_pick_rule(path)
    if rule.fallback is not None:
        rule.column(gate.experts)  # a rule naming an expert the gate does not serve: ConfigError naming both
    label = choice.label or (f"{plugin}-argmax" if choice.argmax else plugin)
    return LoadedGate(label, gate, plugin, path, file_sha256(path), int(gate.settings.n_points), rule)


def _in_gate_order(gate_experts: Sequence[str], experts: Sequence[str]) -> list[str]:
    """``experts`` in the gate's column order when they are the same set (the order of --expert is free), else as
    given, so that check_experts fails naming both lists."""
    return list(gate_experts) if sorted(gate_experts) == sorted(experts) else list(experts)


def _label(loaded: list[LoadedGate], choices: Sequence[GateChoice]) -> list[LoadedGate]:
    labels = [g.label for g in loaded]
    out = []
    for g, c in zip(loaded, choices, strict=True):
        if c.label is None and labels.count(g.label) > 1:
            g = replace(g, label=f"{g.label}-{g.n_points}")
        out.append(g)
    labels = [g.label for g in out]
    twice = sorted({lab for lab in labels if labels.count(lab) > 1})
    if twice:
        raise ConfigError(f"gates labelled {twice} more than once; name each row: --gate LABEL=PATH")
    return out


def clouds_for(library, object_ids: Sequence[str], n_points: int, seed: int = 0) -> torch.Tensor:
    """(n, n_points, 3) float32 clouds of the objects as gate training reads them (object frame, metres); an empty,
    NaN or misshapen cloud is an ArrayError naming the object."""
    return library_clouds(library, object_ids, n_points, seed=seed)


@dataclass(frozen=True)
class Picks:
    """What one gate chose: per object, the expert label and the gate's scores."""

    experts: tuple[str, ...]
    """The gate's expert labels, the columns of ``scores``."""
    chosen: dict[str, str]
    """Object id -> the label of the expert the gate's rule picked (:attr:`LoadedGate.rule`)."""
    scores: dict[str, list[float]]
    """Object id -> the gate's distribution over ``experts`` (sums to 1)."""


def pick_experts(gate: LoadedGate, clouds: torch.Tensor | Sequence[np.ndarray], object_ids: Sequence[str]) -> Picks:
    """One expert per object: ``gate``'s rule (:attr:`LoadedGate.rule`) on its distribution for each cloud (a (n, N,
    3) tensor or a list of (m_i, 3) arrays, object frame, metres; clouds of another size are brought to the gate's, an
    empty or NaN cloud is an ArrayError naming its object)."""
    ids = list(object_ids)
    if not ids:
        return Picks(tuple(gate.gate.experts), {}, {})
    with torch.no_grad():
        probs = gate.gate.predict(clouds, ids).double()
    names = tuple(gate.gate.experts)
    best = gate.rule.choose(probs, names).tolist()
    chosen = {oid: names[j] for oid, j in zip(ids, best, strict=True)}
    scores = {oid: [round(float(p), 6) for p in row] for oid, row in zip(ids, probs, strict=True)}
    return Picks(names, chosen, scores)
