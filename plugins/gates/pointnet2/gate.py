"""The PointNet++ gate: settings and network factory (training and checkpoints: TorchGate)."""

from __future__ import annotations

from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.gating.torch_gate import GateSettings, TorchGate
from ges_plugins.gates.pointnet2.model import PointNet2

__all__ = ["Level", "PointNet2Gate", "PointNet2Settings"]


class Level(ConfigModel):
    """One set-abstraction level."""

    centres: int = Field(..., ge=1, description="centres kept by farthest-point sampling")
    radius: float = Field(..., gt=0, description="ball radius, network units (input_scale metres each)")
    group: int = Field(..., ge=1, description="nearest points within the ball per centre")
    mlp: tuple[int, ...] = Field(..., min_length=1, description="shared MLP widths")


class PointNet2Settings(GateSettings):
    """PointNet++ SSG. Defaults: the paper's classification layout (512 / 128 centres, 32 / 64 points,
    radii 0.2 / 0.4 of a unit sphere) with halved widths (a gate picks among a few experts, not 40
    classes) and radii 0.2 / 0.4 network units = 2 / 4 cm at input_scale 0.1 m, a finger pad's scale."""

    levels: tuple[Level, ...] = Field(
        (
            Level(centres=512, radius=0.2, group=32, mlp=(32, 32, 64)),
            Level(centres=128, radius=0.4, group=64, mlp=(64, 64, 128)),
        ),
        description="set-abstraction levels, input to output",
    )
    global_mlp: tuple[int, ...] = Field((128, 256, 512), min_length=1, description="widths of the whole-cloud level")
    head: tuple[int, ...] = Field((256, 128), description="hidden widths of the classifier")
    dropout: float = Field(0.4, ge=0, lt=1, description="dropout in the classifier (PointNet++: 0.4)")


class PointNet2Gate(TorchGate):
    """Expert selection from a PointNet++ SSG embedding of the object cloud."""

    name = "pointnet2"
    Settings = PointNet2Settings

    def build_model(self, n_experts: int) -> PointNet2:
        s = self.settings
        levels = [lv.model_dump() for lv in s.levels]
        return PointNet2(n_experts, levels, list(s.global_mlp), list(s.head), s.dropout)
