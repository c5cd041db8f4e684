"""CurveNet's building blocks (Xiang et al., "Walk in the Cloud", ICCV 2021), written from the paper.

Tensors are channels-first as in the paper's figures: features (B, C, N), coordinates (B, N, 3) in
network units, neighbour indices (B, N, k) nearest first.

- :class:`LPFA` (local point-feature aggregation): each neighbour's feature difference to its centre plus
  a learned encoding of (p_i, p_j, p_j - p_i), through an MLP, averaged over the k neighbours.
- :class:`CurveGrouping`: picks start points by a learned attention score and walks ``length`` steps
  along the kNN graph; each step a learned policy scores the neighbours from their features and the
  curve's running descriptor (momentum-blended), scores of turning back are damped (crossover
  suppression), and a straight-through hard choice keeps it differentiable.
- :class:`CurveAggregation`: summarizes the curves along and across curves by attention and lets
  every point attend to both summaries; the result is added to the point features.
- :class:`CIC` (curve intervention convolution): a residual bottleneck of curve grouping + aggregation
  and LPFA, after an optional down-sampling (farthest points, max-pool of each one's ball).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ges_core.gating.layers import ConvBN, Pointwise
from ges_core.gating.ops import ball_query, farthest_point_sample, gather_points, knn

__all__ = ["CIC", "LPFA", "CurveAggregation", "CurveGrouping"]

SLOPE = 0.2
"""LeakyReLU negative slope used throughout CurveNet (as in DGCNN, which it builds on)."""


def _neighbours(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """features (B, C, N), idx (B, ...) -> (B, C, ...) the features at idx."""
    return gather_points(features.transpose(1, 2), idx).movedim(-1, 1)


class LPFA(nn.Module):
    """Local point-feature aggregation: (B, C_in, N) -> (B, C_out, N) over the k neighbours ``idx``.

    ``stem``: the first block, which has no input features; it encodes the 9-d geometry of each
    neighbour directly and max-pools (a point's own coordinates are its only feature there).
    """

    def __init__(self, c_in: int, c_out: int, layers: int = 1, *, stem: bool = False) -> None:
        super().__init__()
        self.stem = stem
        self.geometry = None if stem else ConvBN(9, c_in)
        mlp: list[nn.Module] = []
        c = 9 if stem else c_in
        for _ in range(layers):
            mlp += [ConvBN(c, c_out), nn.LeakyReLU(SLOPE)]
            c = c_out
        self.mlp = nn.Sequential(*mlp)

    def forward(self, x: torch.Tensor | None, xyz: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        centre = xyz.unsqueeze(2).expand(-1, -1, idx.shape[-1], -1)  # (B, N, k, 3)
        neighbour = gather_points(xyz, idx)
        geometry = torch.cat([centre, neighbour, neighbour - centre], dim=-1).permute(0, 3, 1, 2)  # (B, 9, N, k)
        if self.stem:
            return self.mlp(geometry).max(dim=-1).values
        assert x is not None and self.geometry is not None
        diff = _neighbours(x, idx) - x.unsqueeze(-1)  # (B, C, N, k)
        local = F.leaky_relu(diff + self.geometry(geometry), SLOPE)
        return self.mlp(local).mean(dim=-1)


def _straight_through_choice(logits: torch.Tensor) -> torch.Tensor:
    """One-hot of the argmax over the last axis whose gradient is the softmax's (straight-through)."""
    soft = torch.softmax(logits, dim=-1)
    hard = F.one_hot(soft.argmax(dim=-1), soft.shape[-1]).to(soft.dtype)
    return hard + soft - soft.detach()


class CurveGrouping(nn.Module):
    """Curves of ``count`` walks of ``length`` steps: x (B, C, N) -> (B, C, count, length) features."""

    def __init__(self, channels: int, count: int, length: int) -> None:
        super().__init__()
        self.count, self.length = count, length
        self.start = Pointwise(channels, 1)
        self.policy = ConvBN(2 * channels, 1)
        self.momentum = ConvBN(2 * channels, 2)

    def forward(self, x: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, C, N) features; idx: (B, N, k) neighbours without the point itself. Returns the curves'
        features (B, C, count, length) and the features re-weighted by the start attention (B, C, N)."""
        score = torch.sigmoid(self.start(x))  # (B, 1, N)
        x = x * score
        current = score.squeeze(1).topk(min(self.count, x.shape[-1]), dim=-1).indices  # (B, count)
        descriptor = _neighbours(x, current)  # (B, C, count)
        step_feature, steps = None, []
        for _ in range(self.length):
            if step_feature is not None:  # blend the last step into the running descriptor
                w = torch.softmax(self.momentum(torch.cat([step_feature, descriptor], dim=1)), dim=1)
                descriptor = w[:, :1] * step_feature + w[:, 1:] * descriptor
            candidates = gather_points(idx, current)  # (B, count, k) int64
            cand_feat = _neighbours(x, candidates)  # (B, C, count, k)
            pair = torch.cat([cand_feat, descriptor.unsqueeze(-1).expand_as(cand_feat)], dim=1)
            logits = self.policy(pair).squeeze(1)  # (B, count, k)
            if step_feature is not None:
                logits = logits * self._no_turning_back(step_feature, descriptor, cand_feat)
            step_feature, pick = self._step(logits, cand_feat)  # (B, C, count), (B, count, 1)
            current = torch.gather(candidates, -1, pick).squeeze(-1)
            steps.append(step_feature)
        return torch.stack(steps, dim=-1), x

    @staticmethod
    def _step(logits: torch.Tensor, cand_feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The chosen candidate's features (B, C, count) and index (B, count, 1): a straight-through hard
        choice when gradients are wanted, else the argmax's features gathered directly (same values, fewer
        steps: the walk is mostly per-step overhead at inference)."""
        if torch.is_grad_enabled():
            choice = _straight_through_choice(logits)
            return (cand_feat * choice.unsqueeze(1)).sum(dim=-1), choice.argmax(dim=-1, keepdim=True)
        pick = logits.argmax(dim=-1, keepdim=True)
        index = pick.unsqueeze(1).expand(-1, cand_feat.shape[1], -1, -1)
        return torch.gather(cand_feat, -1, index).squeeze(-1), pick

    @staticmethod
    def _no_turning_back(here: torch.Tensor, descriptor: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        """(B, count, k) in [0, 1]: 1 + cos of the angle between the walk's last move (here - descriptor)
        and the move to each candidate, clipped; a candidate behind the walk gets ~0 (crossover
        suppression). No gradient: it shapes the choice, it is not learned."""
        with torch.no_grad():
            came = (here - descriptor).unsqueeze(-1)  # (B, C, count, 1)
            go = cand - here.unsqueeze(-1)  # (B, C, count, k)
            cos = F.cosine_similarity(came, go, dim=1, eps=1e-8)
            return (1.0 + cos).clamp(0.0, 1.0)


class CurveAggregation(nn.Module):
    """Adds what the curves say to every point: x (B, C, N), curves (B, C, count, length) -> (B, C, N)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        mid = max(channels // 2, 1)
        self.weight = Pointwise(channels, 1)
        self.key_across = Pointwise(channels, mid)
        self.key_along = Pointwise(channels, mid)
        self.query = Pointwise(channels, mid)
        self.value_across = Pointwise(mid, mid)
        self.value_along = Pointwise(mid, mid)
        self.out = ConvBN(2 * mid, channels)

    def forward(self, x: torch.Tensor, curves: torch.Tensor) -> torch.Tensor:
        w = self.weight(curves)  # (B, 1, count, length)
        per_curve = (curves * torch.softmax(w, dim=-1)).sum(dim=-1)  # (B, C, count): each curve summarized
        per_step = (curves * torch.softmax(w, dim=-2)).sum(dim=-2)  # (B, C, length): each step across curves
        k_across, k_along = self.key_across(per_curve), self.key_along(per_step)
        q = self.query(x).transpose(1, 2)  # (B, N, mid)
        att_across = torch.softmax(q @ k_across, dim=-1)  # (B, N, count)
        att_along = torch.softmax(q @ k_along, dim=-1)  # (B, N, length)
        got_across = att_across @ self.value_across(k_across).transpose(1, 2)  # (B, N, mid)
        got_along = att_along @ self.value_along(k_along).transpose(1, 2)
        merged = torch.cat([got_across, got_along], dim=-1).transpose(1, 2)  # (B, 2 mid, N)
        return F.leaky_relu(x + self.out(merged), SLOPE)


class CIC(nn.Module):
    """Curve intervention convolution: (xyz (B, N, 3), x (B, C_in, N)) -> (xyz (B, M, 3), (B, C_out, M), kNN).

    ``points``: down-sample to this many farthest points first (each keeps the max of its ``k`` nearest
    within ``radius``), None to keep all. ``curves``: (count, length) of the curve grouping, None for a
    block without curves (the paper's later stages).
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        *,
        k: int,
        points: int | None,
        radius: float,
        bottleneck: int,
        curves: tuple[int, int] | None,
    ) -> None:
        super().__init__()
        self.k, self.points, self.radius = k, points, radius
        mid = max(c_in // bottleneck, 1)
        self.reduce = nn.Sequential(ConvBN(c_in, mid), nn.LeakyReLU(SLOPE))
        self.grouping = CurveGrouping(mid, *curves) if curves else None
        self.aggregation = CurveAggregation(mid) if curves else None
        self.lpfa = LPFA(mid, mid)
        self.expand = ConvBN(mid, c_out)
        self.shortcut = ConvBN(c_in, c_out) if c_in != c_out else nn.Identity()

    def forward(
        self, xyz: torch.Tensor, x: torch.Tensor, idx: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``idx``: the (B, N, k + 1) nearest neighbours of ``xyz`` (self first) if known; returns the
        block's points, features and their neighbours (reused by the next block on the same points: the
        kNN of 1024 points is most of CurveNet's CPU time otherwise)."""
        if self.points is not None and self.points < xyz.shape[1]:
            xyz, x = self._pool(xyz, x)
            idx = None
        if idx is None:
            idx = knn(xyz, self.k + 1)  # nearest first: column 0 is the point itself
        y = self.reduce(x)
        if self.grouping is not None and self.aggregation is not None:
            curves, y = self.grouping(y, idx[..., 1:])
            y = self.aggregation(y, curves)
        y = self.expand(self.lpfa(y, xyz, idx[..., : self.k]))
        return xyz, F.leaky_relu(y + self.shortcut(x), SLOPE), idx

    def _pool(self, xyz: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        centres = gather_points(xyz, farthest_point_sample(xyz, self.points))
        idx = ball_query(xyz, centres, self.radius, self.k)  # (B, M, k)
        return centres, _neighbours(x, idx).max(dim=-1).values
