"""PointNet++ with single-scale grouping (Qi et al., NeurIPS 2017), as a gate network.

Each set-abstraction level picks centres by farthest-point sampling, groups the nearest points within
a ball around each, runs a shared MLP on (offset / radius, features) and max-pools each group; a last
level pools the whole cloud. A fully connected head gives one logit per expert.
"""

from __future__ import annotations

import torch
from torch import nn

from ges_core.gating.layers import ConvBN
from ges_core.gating.ops import ball_query, farthest_point_sample, gather_points

__all__ = ["PointNet2", "SetAbstraction"]


def _shared_mlp(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip(channels[:-1], channels[1:], strict=False):
        layers += [ConvBN(c_in, c_out), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """One level: (B, N, 3) xyz, (B, N, C) features -> (B, M, 3) centres, (B, M, C') pooled features.

    ``centres`` None pools the whole cloud into one point at the origin.
    """

    def __init__(self, centres: int | None, radius: float, group: int, in_channels: int, mlp: list[int]) -> None:
        super().__init__()
        self.centres, self.radius, self.group = centres, radius, group
        self.mlp = _shared_mlp([in_channels + 3, *mlp])

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        if self.centres is None:
            new_xyz = xyz.new_zeros(xyz.shape[0], 1, 3)
            grouped = xyz.unsqueeze(1)  # (B, 1, N, 3): every point in one group
            feats = None if features is None else features.unsqueeze(1)
        else:
            new_xyz = gather_points(xyz, farthest_point_sample(xyz, self.centres))
            idx = ball_query(xyz, new_xyz, self.radius, self.group)  # (B, M, K)
            grouped = (gather_points(xyz, idx) - new_xyz.unsqueeze(2)) / self.radius
            feats = None if features is None else gather_points(features, idx)
        x = grouped if feats is None else torch.cat([grouped, feats], dim=-1)  # (B, M, K, 3 + C)
        x = self.mlp(x.permute(0, 3, 1, 2))  # (B, C', M, K)
        return new_xyz, x.max(dim=-1).values.transpose(1, 2)


class PointNet2(nn.Module):
    """(B, N, 3) clouds in network units -> (B, n_experts) logits."""

    def __init__(
        self, n_experts: int, levels: list[dict], global_mlp: list[int], head: list[int], dropout: float
    ) -> None:
        super().__init__()
        blocks, c = [], 0
        for level in levels:
            blocks.append(SetAbstraction(level["centres"], level["radius"], level["group"], c, list(level["mlp"])))
            c = level["mlp"][-1]
        self.levels = nn.ModuleList(blocks)
        self.pool = SetAbstraction(None, 1.0, 0, c, list(global_mlp))
        fc: list[nn.Module] = []
        c = global_mlp[-1]
        for width in head:
            fc += [nn.Linear(c, width, bias=False), nn.BatchNorm1d(width), nn.ReLU(inplace=True), nn.Dropout(dropout)]
            c = width
        self.head = nn.Sequential(*fc, nn.Linear(c, n_experts))

    def forward(self, xyz: torch.Tensor) -> torch.Tensor:
        features = None
        for level in self.levels:
            xyz, features = level(xyz, features)
        _, pooled = self.pool(xyz, features)
        return self.head(pooled.squeeze(1))
