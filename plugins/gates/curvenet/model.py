"""CurveNet as a gate network: an LPFA stem, stages of two CIC blocks, max + mean pooling, an MLP head."""

from __future__ import annotations

import torch
from torch import nn

from ges_core.gating.layers import ConvBN, sequential_last
from ges_core.gating.ops import knn
from ges_plugins.gates.curvenet.blocks import CIC, LPFA

__all__ = ["CurveNet"]


class CurveNet(nn.Module):
    """(B, N, 3) clouds in network units -> (B, n_experts) logits.

    stages: per stage a dict with ``channels``, ``points`` (None: keep), ``radius`` and ``curves``
    ((count, length) or None); each stage is two CIC blocks, the first changing the width (bottleneck 2),
    the second keeping it (bottleneck 4), as the paper's classification network.
    """

    def __init__(
        self, n_experts: int, *, k: int, stem: int, stages: list[dict], embed: int, head: list[int], dropout: float
    ) -> None:
        super().__init__()
        self.k = k
        self.stem = LPFA(9, stem, stem=True)
        blocks, c = [], stem
        for s in stages:
            common = {"k": k, "points": s["points"], "radius": s["radius"], "curves": s["curves"]}
            blocks.append(CIC(c, s["channels"], bottleneck=2, **common))
            blocks.append(CIC(s["channels"], s["channels"], bottleneck=4, **common))
            c = s["channels"]
        self.blocks = nn.ModuleList(blocks)
        self.embed = nn.Sequential(ConvBN(c, embed), nn.ReLU(inplace=True))
        fc: list[nn.Module] = []
        c = 2 * embed
        for width in head:
            fc += [nn.Linear(c, width, bias=False), nn.BatchNorm1d(width), nn.ReLU(inplace=True), nn.Dropout(dropout)]
            c = width
        self.head = nn.Sequential(*fc, nn.Linear(c, n_experts))

    def forward(self, xyz: torch.Tensor) -> torch.Tensor:
        idx = knn(xyz, self.k + 1)  # shared by the stem and every block until the points are down-sampled
        x = self.stem(None, xyz, idx[..., : self.k])  # (B, N, stem): channels-last from here on
        for block in self.blocks:
            xyz, x, idx = block(xyz, x, idx)
        x = sequential_last(self.embed, x)  # (B, M, embed)
        return self.head(torch.cat([x.amax(dim=1), x.mean(dim=1)], dim=-1))
