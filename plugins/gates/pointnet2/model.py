"""PointNet++ with single-scale grouping (Qi et al., NeurIPS 2017), as a gate network.

Each set-abstraction level picks centres by farthest-point sampling, groups the nearest points within
a ball around each, runs a shared MLP on (offset / radius, features) and max-pools each group; a last
level pools the whole cloud. A fully connected head gives one logit per expert.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ges_core.gating.layers import ConvBN, sequential_last
from ges_core.gating.ops import ball_query, farthest_point_sample, gather_points, max_over_neighbours

__all__ = ["PointNet2", "SetAbstraction"]


def _shared_mlp(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip(channels[:-1], channels[1:], strict=False):
        layers += [ConvBN(c_in, c_out), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """One level: (B, N, 3) xyz, (B, N, C) features -> (B, M, 3) centres, (B, M, C') pooled features.

    ``centres`` None pools the whole cloud into one point at the origin. Channels-last throughout (a group
    is one row gather); the first layer of the shared MLP, linear in (offset / radius, features), is split
    into a per-point part (computed once per point, gathered) and a per-centre part (the centre's own
    offset), instead of running on every (centre, member) row: the same values up to rounding
    (tests/test_gate_ops.py compares with the direct formula).
    """

    def __init__(self, centres: int | None, radius: float, group: int, in_channels: int, mlp: list[int]) -> None:
        super().__init__()
        self.centres, self.radius, self.group = centres, radius, group
        self.mlp = _shared_mlp([in_channels + 3, *mlp])

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        if self.centres is None:
            new_xyz = xyz.new_zeros(xyz.shape[0], 1, 3)
            x = xyz if features is None else torch.cat([xyz, features], dim=-1)  # (B, N, 3 + C): one group
            return new_xyz, sequential_last(self.mlp, x).amax(dim=1, keepdim=True)
        new_xyz = gather_points(xyz, farthest_point_sample(xyz, self.centres))
        idx = ball_query(xyz, new_xyz, self.radius, self.group)  # (B, M, K)
        first = self.mlp[0]
        weight, bias = first.folded()
        w_offset = weight[:, :3] / self.radius  # pre(m, j) = w_offset (p_j - c_m) + w_feat f_j + bias
        point = F.linear(xyz, w_offset)  # (B, N, C1): the members' part, once per point
        if features is not None:
            point = point.add_(F.linear(features, weight[:, 3:]))
        centre = F.linear(new_xyz, w_offset)
        if bias is not None:
            centre = centre - bias
        pre = gather_points(point, idx).sub_(centre.unsqueeze(2))  # (B, M, K, C1)
        out = sequential_last(list(self.mlp)[1:], first.normalize(pre), fresh=True)
        return new_xyz, max_over_neighbours(out)


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
