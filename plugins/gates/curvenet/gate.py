"""The CurveNet gate: settings and network factory (training and checkpoints: TorchGate)."""

from __future__ import annotations

from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.gating.torch_gate import GateSettings, TorchGate
from ges_plugins.gates.curvenet.model import CurveNet

__all__ = ["CurveNetGate", "CurveNetSettings", "Stage"]


class Stage(ConfigModel):
    """One CurveNet stage (two CIC blocks)."""

    channels: int = Field(..., ge=2, description="output width of the stage")
    points: int | None = Field(..., ge=1, description="down-sample to this many farthest points first (None: keep all)")
    radius: float = Field(..., gt=0, description="ball of the down-sampling max-pool, network units")
    curves: tuple[int, int] | None = Field(..., description="(count, length) of the walks, None: no curve grouping")


class CurveNetSettings(GateSettings):
    """CurveNet. Defaults: the paper's classification layout (an LPFA stem, four stages of two CIC blocks,
    curve grouping and aggregation in the first two stages, widths doubling per stage) made lighter for a
    gate that picks among a few experts, not 40 classes, and for inference on one CPU core
    (benchmarks/gate_speed.py): half the widths (32 .. 256 instead of 64 .. 512), k = 10 neighbours instead
    of 20, 32 curves of 5 steps instead of 100 of 5 (the official code's setting; the paper also has 50 of
    10), and the stages on 1024 -> 256 -> 64 -> 16 points instead of 1024 -> 1024 -> 256 -> 64.

    k 12 -> 10 and walks of 8 -> 5 steps (December 2026) took ~10 % off the CPU time per object; on
    benchmarks/gate_study.py's setup (48 objects, 12 epochs, seed 0) the gate accuracy was 77.8 % train /
    50.0 % validation against 61.1 % / 41.7 % with the previous values (results/gate_study_curvenet_*.json).
    Checkpoints keep their own settings, so those trained with the previous values load unchanged."""

    k: int = Field(10, ge=2, description="neighbours of LPFA and of the walks (CurveNet: 20)")
    stem: int = Field(16, ge=1, description="width of the LPFA stem (CurveNet: 32)")
    stages: tuple[Stage, ...] = Field(
        (
            Stage(channels=32, points=None, radius=0.2, curves=(32, 5)),
            Stage(channels=64, points=256, radius=0.3, curves=(32, 5)),
            Stage(channels=128, points=64, radius=0.5, curves=None),
            Stage(channels=256, points=16, radius=1.0, curves=None),
        ),
        min_length=1,
        description="stages, input to output",
    )
    embed: int = Field(256, ge=1, description="width before the max + mean pooling (CurveNet: 512)")
    head: tuple[int, ...] = Field((256,), description="hidden widths of the classifier (CurveNet: 512)")
    dropout: float = Field(0.5, ge=0, lt=1, description="dropout in the classifier (CurveNet: 0.5)")


class CurveNetGate(TorchGate):
    """Expert selection from a CurveNet embedding of the object cloud."""

    name = "curvenet"
    Settings = CurveNetSettings

    def build_model(self, n_experts: int) -> CurveNet:
        s = self.settings
        stages = [st.model_dump() for st in s.stages]
        return CurveNet(
            n_experts, k=s.k, stem=s.stem, stages=stages, embed=s.embed, head=list(s.head), dropout=s.dropout
        )
