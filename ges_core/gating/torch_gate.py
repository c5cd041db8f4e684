"""A gate whose scores come from a torch network on the object's point cloud (CurveNet, PointNet++).

A plugin subclasses :class:`TorchGate`, names its settings model and builds its network; this class
does the rest: input checks, scaling to network units, softmax, training (``fit``), checkpoints, and
averaging several trained networks of one plugin into one gate (:meth:`TorchGate.averaged`, what
``train.folds`` makes: :mod:`ges_core.gating.folds`).
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel, parse_model
from ges_core.errors import ConfigError
from ges_core.gating.checkpoint import read_checkpoint, write_checkpoint
from ges_core.gating.inputs import gate_input
from ges_core.gating.train import GateData, TrainConfig, TrainResult, train_model
from ges_core.policy import Gate

__all__ = ["GateSettings", "MeanOfMembers", "TorchGate"]


class GateSettings(ConfigModel):
    """Settings every point-cloud gate has (a plugin's settings model extends this)."""

    n_points: int = Field(1024, ge=16, description="points per object cloud (the paper: 1024 beats 4096)")
    input_scale: float = Field(
        0.1,
        gt=0,
        description="metres per network unit: clouds are divided by it, so a 10 cm object spans ~1 unit (the "
        "range the backbones' radii are given in) while its metric size, which decides the expert, is kept",
    )


class MeanOfMembers(torch.nn.Module):
    """Several networks of one layout as one: ``log(mean_m softmax(member_m(x)))``, so the gate's softmax of it is
    the members' mean probability. x: (B, N, 3) network units; returns (B, k) log-probabilities."""

    def __init__(self, members: Sequence[torch.nn.Module]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ConfigError(f"an averaged gate needs 2+ networks, got {len(members)}")
        self.members = torch.nn.ModuleList(members)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        probs = torch.stack([torch.softmax(m(x), dim=-1) for m in self.members]).mean(dim=0)
        return torch.log(probs.clamp_min(torch.finfo(probs.dtype).tiny))


class TorchGate(Gate):
    """A gate scoring experts with ``softmax(network(points / input_scale))``."""

    Settings: ClassVar[type[GateSettings]] = GateSettings

    def __init__(self, **settings: Any) -> None:
        self.settings = parse_model(self.Settings, settings, where=f"gate '{self.name}' settings")
        self.experts: tuple[str, ...] = ()
        self.model: torch.nn.Module | None = None
        self.train_info: dict[str, Any] = {}

    @abstractmethod
    def build_model(self, n_experts: int) -> torch.nn.Module:
        """A fresh network: (B, N, 3) clouds in network units -> (B, n_experts) logits."""

    # -- use ----------------------------------------------------------------------------------
    def predict(
        self, points: torch.Tensor | Sequence[np.ndarray], object_ids: Sequence[str] | None = None
    ) -> torch.Tensor:
        """(n, k) float32 expert probabilities (rows sum to 1, columns :attr:`experts`) for clouds
        (n, N, 3) or a list of (m_i, 3), object frame, metres; see :func:`ges_core.gating.inputs.gate_input`."""
        model = self._trained()
        x = gate_input(points, self.settings.n_points, object_ids)
        if model.training:
            model.eval()
        with torch.inference_mode():  # no autograd bookkeeping at all (no_grad still counts tensor versions)
            probs = torch.softmax(model(x / self.settings.input_scale), dim=-1)
        return probs.clone()  # an ordinary tensor: an inference tensor cannot enter autograd later

    def _trained(self) -> torch.nn.Module:
        if self.model is None:
            raise ConfigError(f"gate '{self.name}' is not trained: fit it (ges train-gate) or load a checkpoint")
        return self.model

    # -- training -----------------------------------------------------------------------------
    def fit(
        self,
        data: GateData,
        config: TrainConfig | None = None,
        *,
        log_dir: str | Path | None = None,
        on_epoch: Callable[[int, TrainResult], None] | None = None,
        state_file: str | Path | None = None,
        state_every: int = 5,
        resume: bool = False,
        fold: int | None = None,
        soft_targets: torch.Tensor | None = None,
    ) -> TrainResult:
        """Train a fresh network on ``data`` (clouds in metres, any size: brought to ``n_points``); the
        experts become ``data.rates.experts``. Seeded by ``config.seed``. ``state_file``, ``state_every``,
        ``resume``, ``fold``, ``soft_targets``: the resumable training state, the held-out fold and targets other
        than the normalized rates (:func:`ges_core.gating.train.train_model`)."""
        config = config or TrainConfig()
        ids = data.rates.object_ids
        clouds = gate_input(data.clouds, self.settings.n_points, ids) / self.settings.input_scale
        torch.manual_seed(config.seed)
        self.experts = data.rates.experts
        self.model = self.build_model(len(self.experts))
        result = train_model(
            self.model,
            GateData(data.rates, clouds, data.categories),
            config,
            log_dir=log_dir,
            on_epoch=on_epoch,
            state_file=state_file,
            state_every=state_every,
            resume=resume,
            fold=fold,
            soft_targets=soft_targets,
        )
        self.train_info = {
            "config": config.model_dump(mode="json"),
            "summary": result.summary(),
            "train_ids": result.train_ids,
            "val_ids": result.val_ids,
            "dropped_ids": result.dropped_ids,
        }
        return result

    @property
    def members(self) -> int:
        """How many networks the gate averages (1: a single network; :meth:`averaged`)."""
        return len(self.model.members) if isinstance(self.model, MeanOfMembers) else 1

    @classmethod
    def averaged(cls, gates: Sequence[TorchGate], train_info: dict[str, Any] | None = None) -> TorchGate:
        """One gate scoring with the mean probability of ``gates`` (2+ trained single networks of this plugin, with
        equal settings and experts: a ConfigError names what differs). ``train_info``: stored in its checkpoint."""
        first = gates[0].settings.model_dump()
        for g in gates:
            if type(g) is not cls or g.members != 1:
                raise ConfigError(f"gate '{cls.name}' averages single '{cls.name}' networks, not a {g.name} gate "
                                  f"of {g.members} network(s)")  # fmt: skip
            if g.experts != gates[0].experts:
                raise ConfigError(f"gate '{cls.name}': networks trained for other experts cannot be averaged "
                                  f"({list(gates[0].experts)} vs {list(g.experts)})")  # fmt: skip
            if g.settings != gates[0].settings:
                differ = sorted(k for k, v in g.settings.model_dump().items() if first[k] != v)
                raise ConfigError(f"gate '{cls.name}': networks of other settings cannot be averaged ({differ} differ)")
        out = cls(**first)
        out.experts = gates[0].experts
        out.model = MeanOfMembers([g._trained() for g in gates])
        out.model.eval()
        out.train_info = train_info or {}
        return out

    def _build(self, members: int) -> torch.nn.Module:
        k = len(self.experts)
        return self.build_model(k) if members == 1 else MeanOfMembers([self.build_model(k) for _ in range(members)])

    # -- checkpoints --------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the network(s), settings and experts to ``path`` (atomically)."""
        model = self._trained()
        write_checkpoint(
            path,
            {
                "gate": self.name,
                "experts": list(self.experts),
                "settings": self.settings.model_dump(mode="json"),
                "state": model.state_dict(),
                "train": self.train_info,
                "members": self.members,
            },
        )

    @classmethod
    def load(cls, path: str | Path) -> TorchGate:
        """The gate saved at ``path`` by this plugin (one network, or the averaged networks of ``members``)."""
        data = read_checkpoint(path, gate=cls.name)
        gate = cls(**data["settings"])
        gate.experts = tuple(data["experts"])
        gate.model = gate._build(int(data.get("members", 1)))
        gate.model.load_state_dict(data["state"])
        gate.model.eval()
        gate.train_info = data.get("train", {})
        return gate
