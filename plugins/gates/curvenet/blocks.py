"""CurveNet's building blocks (Xiang et al., "Walk in the Cloud", ICCV 2021), written from the paper.

Tensors are channels-last, so that a neighbourhood is one row gather: features (B, N, C), coordinates
(B, N, 3) in network units, neighbour indices (B, N, k) nearest first. (The state dict is the same as
the channels-first version's: layers keep their (C_out, C_in) weights.)

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

Speed (inference on one CPU core is what a gate is for, benchmarks/gate_speed.py): a layer applied to a
concatenation is split into the parts' maps (``W [a; b] = W_a a + W_b b``), and a part that depends on a
point alone is computed once per point and gathered, instead of once per (point, neighbour) pair or per walk
step: the LPFA geometry encoding (9 -> C on N k pairs becomes 3 -> C on N points, twice) and the walk's
policy layer (its candidate half). The values are those of the direct formulas
up to rounding (tests/test_gate_ops.py keeps the direct version and compares, in train and eval mode).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ges_core.gating.layers import ConvBN, Pointwise, sequential_last
from ges_core.gating.ops import (
    ball_from_neighbours,
    farthest_point_sample,
    gather_points,
    knn,
    max_over_neighbours,
)

__all__ = ["CIC", "LPFA", "CurveAggregation", "CurveGrouping"]

SLOPE = 0.2
"""LeakyReLU negative slope used throughout CurveNet (as in DGCNN, which it builds on)."""


def _geometry_parts(layer: ConvBN, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The linear part of ``layer`` (9 -> C) on the rows (p_i, p_j, p_j - p_i), split per point: returns
    own (B, N, C) (bias included) and other (B, N, C) with ``pre(i, j) = own[i] + other[j]``."""
    w_own, w_other, bias = layer.derived("geometry", _split_geometry)
    return F.linear(xyz, w_own, bias), F.linear(xyz, w_other)


def _split_geometry(
    weight: torch.Tensor, bias: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """(C, 9) weight on (p_i, p_j, p_j - p_i) -> the (C, 3) maps of p_i and of p_j, and the bias."""
    w_centre, w_neighbour, w_offset = weight[:, :3], weight[:, 3:6], weight[:, 6:9]
    return w_centre - w_offset, w_neighbour + w_offset, bias


class LPFA(nn.Module):
    """Local point-feature aggregation: (B, N, C_in) -> (B, N, C_out) over the k neighbours ``idx``.

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
        """x: (B, N, C_in) or None for the stem; xyz: (B, N, 3); idx: (B, N, k) -> (B, N, C_out)."""
        if self.stem:
            first = self.mlp[0]
            own, other = _geometry_parts(first, xyz)
            if not self.training and len(self.mlp) == 2:  # one layer and its LeakyReLU, no BatchNorm left
                # max_j leaky(own_i + other_j) = leaky(own_i + max_j other_j): rounding and LeakyReLU are
                # monotone, so the same values without the (B, N, k, C) sum and activation (~0.1 ms)
                return F.leaky_relu_(max_over_neighbours(gather_points(other, idx)).add_(own), SLOPE)
            local = first.normalize(gather_points(other, idx).add_(own.unsqueeze(2)))  # (B, N, k, C_out)
            return max_over_neighbours(sequential_last(list(self.mlp)[1:], local, fresh=True))
        assert x is not None and self.geometry is not None
        own, other = _geometry_parts(self.geometry, xyz)
        if self.training:  # the encoding's BatchNorm needs its batch statistics: build it
            encoding = self.geometry.normalize(gather_points(other, idx) + own.unsqueeze(2))
            local = (gather_points(x, idx) - x.unsqueeze(2)).add_(encoding)
        else:  # x_j - x_i + own_i + other_j: one gather of (x + other)
            local = gather_points(x + other, idx).add_((own - x).unsqueeze(2))  # (B, N, k, C_in)
        return sequential_last(self.mlp, F.leaky_relu_(local, SLOPE)).mean(dim=2)


def _straight_through_choice(logits: torch.Tensor) -> torch.Tensor:
    """One-hot of the argmax over the last axis whose gradient is the softmax's (straight-through)."""
    soft = torch.softmax(logits, dim=-1)
    hard = F.one_hot(soft.argmax(dim=-1), soft.shape[-1]).to(soft.dtype)
    return hard + soft - soft.detach()


class CurveGrouping(nn.Module):
    """Curves of ``count`` walks of ``length`` steps: x (B, N, C) -> (B, count, length, C) features."""

    def __init__(self, channels: int, count: int, length: int) -> None:
        super().__init__()
        self.count, self.length = count, length
        self.start = Pointwise(channels, 1)
        self.policy = ConvBN(2 * channels, 1)  # on (candidate features, descriptor)
        self.momentum = ConvBN(2 * channels, 2)  # on (last step's features, descriptor)

    def forward(self, x: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, N, C) features; idx: (B, N, k) neighbours without the point itself. Returns the curves'
        features (B, count, length, C) and the features re-weighted by the start attention (B, N, C).

        The walk works on rows of the (B N) points: each step gathers its candidates' rows (features and
        the candidate half of the policy, computed once per point) with one ``index_select``.
        """
        score = torch.sigmoid(self.start.last(x))  # (B, N, 1)
        x = x * score
        b, n, c = x.shape
        count = min(self.count, n)
        points = x.reshape(b * n, c)
        if not self.training and not torch.is_grad_enabled() and x.device.type == "cpu":
            w_candidate, c_policy = self.policy.derived("walk", lambda w, bias: _walk_policy(w, bias, c))
            c_gate = self.momentum.derived("walk", lambda w, bias: _walk_gate(w, bias))
            rows = torch.cat([x, F.linear(x, w_candidate)], dim=-1).view(b * n, c + 1)
            neighbours, current = _walk_rows(idx, score, count)
            walked = _walk_numpy(points, rows, neighbours, current, c_policy, c_gate, self.length)
            return walked.view(b, count, self.length, c), x
        w_policy, b_policy = self.policy.folded()
        w_momentum, b_momentum = self.momentum.folded()
        rows = torch.cat([x, F.linear(x, w_policy[:, :c])], dim=-1).view(b * n, c + 1)
        neighbours, current = _walk_rows(idx, score, count)
        descriptor = points.index_select(0, current)  # (B count, C)
        step: torch.Tensor | None = None
        steps = []
        for _ in range(self.length):
            if step is not None:  # blend the last step into the running descriptor
                w = self.momentum.normalize(F.linear(torch.cat([step, descriptor], dim=-1), w_momentum, b_momentum))
                # softmax over the two weights = (sigmoid(w0 - w1), 1 - that)
                descriptor = torch.lerp(descriptor, step, torch.sigmoid(w[:, :1] - w[:, 1:]))
            candidates = neighbours.index_select(0, current)  # (B count, k)
            cand = rows.index_select(0, candidates.view(-1)).view(b * count, -1, c + 1)  # (B count, k, C + 1)
            pre = cand[..., c] + F.linear(descriptor, w_policy[:, c:], b_policy)  # (B count, k)
            logits = self.policy.normalize(pre.unsqueeze(-1)).squeeze(-1)
            if step is not None:
                logits = logits * self._no_turning_back(step, descriptor, cand[..., :c])
            step, current = self._step(logits, candidates, cand[..., :c], points)
            steps.append(step)
        return torch.stack(steps, dim=1).view(b, count, self.length, c), x

    @staticmethod
    def _step(
        logits: torch.Tensor, candidates: torch.Tensor, cand_feat: torch.Tensor, points: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The chosen candidate's features (B count, C) and row (B count,): a straight-through hard choice
        when gradients are wanted, else the argmax's row gathered directly (same values, fewer steps: the
        walk is mostly per-step overhead at inference). logits, candidates: (B count, k); cand_feat:
        (B count, k, C); points: (B N, C)."""
        if torch.is_grad_enabled():
            choice = _straight_through_choice(logits)  # (B count, k)
            pick = choice.argmax(dim=-1, keepdim=True)
            feature = (cand_feat * choice.unsqueeze(-1)).sum(dim=1)
            return feature, torch.gather(candidates, -1, pick).squeeze(-1)
        current = torch.gather(candidates, -1, logits.argmax(dim=-1, keepdim=True)).squeeze(-1)
        return points.index_select(0, current), current

    @staticmethod
    def _no_turning_back(here: torch.Tensor, descriptor: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        """(B count, k) in [0, 1]: 1 + cos of the angle between the walk's last move (here - descriptor)
        and the move to each candidate, clipped; a candidate behind the walk gets ~0 (crossover
        suppression). No gradient: it shapes the choice, it is not learned. here, descriptor:
        (B count, C); cand: (B count, k, C)."""
        with torch.no_grad():
            came = (here - descriptor).unsqueeze(1)  # (B count, 1, C)
            go = cand - here.unsqueeze(1)  # (B count, k, C)
            cos = F.cosine_similarity(came, go, dim=-1, eps=1e-8)
            return (1.0 + cos).clamp(0.0, 1.0)


def _walk_rows(idx: torch.Tensor, score: torch.Tensor, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The walk's neighbour rows (B N, k) and start rows (B count,) (the ``count`` highest of score
    (B, N, 1)) as row numbers of the (B N) points; idx: (B, N, k) neighbours within each cloud."""
    b, n, _ = idx.shape
    start = score.view(b, n).topk(count, dim=-1).indices
    if b == 1:  # row numbers are the indices themselves (no offset tensor to build: ~5 calls fewer)
        return idx.reshape(n, -1), start.view(-1)
    offset = torch.arange(b, device=idx.device).view(b, 1) * n  # row number of each cloud's first point
    return (idx + offset.unsqueeze(-1)).view(b * n, -1), (start + offset).view(-1)


def _walk_policy(
    w_policy: torch.Tensor, b_policy: torch.Tensor, c: int
) -> tuple[torch.Tensor, tuple[np.ndarray, np.ndarray]]:
    """The walk's policy constants from the folded (1, 2C) weight and bias: the candidate half (a view,
    computed per point in torch) and, for :func:`_walk_numpy`, the descriptor half and the bias."""
    return w_policy[:, :c], (w_policy.detach().numpy()[0, c:], b_policy.detach().numpy()[0])


def _walk_gate(w_momentum: torch.Tensor, b_momentum: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_walk_numpy`'s momentum constants: softmax over two logits = sigmoid of their difference."""
    wm, bm = w_momentum.detach().numpy(), b_momentum.detach().numpy()
    return wm[0] - wm[1], bm[0] - bm[1]


def _walk_numpy(
    points: torch.Tensor,
    rows: torch.Tensor,
    neighbours: torch.Tensor,
    current: torch.Tensor,
    policy: tuple[np.ndarray, np.ndarray],
    gate: tuple[np.ndarray, np.ndarray],
    length: int,
) -> torch.Tensor:
    """:meth:`CurveGrouping.forward`'s walk at inference on the CPU (eval mode, BatchNorm folded, argmax
    choices), in numpy: the same steps, whose small array operations cost ~0.5 us each against ~2 us for
    torch's (0.33 against 0.95 ms for 32 curves of 8 steps on 1024 points, one core). Arguments as there:
    points (B N, C), rows (B N, C + 1), neighbours (B N, k) and current (B count,) rows, the folded
    weights' constants (:func:`_walk_policy`, :func:`_walk_gate`: derived once per model, not per call);
    returns (B count, length, C). tests/test_gate_ops.py checks it against the torch walk."""
    pts, rws, nbr, cur = (t.detach().numpy() for t in (points, rows, neighbours, current))
    c, k = pts.shape[1], nbr.shape[1]
    (wp, bp), (w_gate, b_gate) = policy, gate
    first_of_row = np.arange(len(cur)) * k  # flat index of each curve's first candidate
    out = np.empty((len(cur), length, c), dtype=pts.dtype)
    descriptor, step = pts.take(cur, axis=0), None  # take: cheaper than fancy indexing on small arrays
    for i in range(length):
        if step is not None:
            gate = 0.5 + 0.5 * np.tanh(0.5 * (step @ w_gate[:c] + descriptor @ w_gate[c:] + b_gate))  # sigmoid
            descriptor = descriptor + gate[:, None] * (step - descriptor)
        candidates = nbr.take(cur, axis=0)  # (B count, k)
        cand = rws.take(candidates, axis=0)  # (B count, k, C + 1)
        logits = cand[..., c] + (descriptor @ wp + bp)[:, None]
        if step is not None:  # crossover suppression, as CurveGrouping._no_turning_back
            came, go = step - descriptor, cand[..., :c] - step[:, None]
            go_norm = np.maximum(np.sqrt(np.einsum("qkc,qkc->qk", go, go)), 1e-8)
            came_norm = np.maximum(np.sqrt(np.einsum("qc,qc->q", came, came)), 1e-8)
            cos = np.einsum("qkc,qc->qk", go, came) / (go_norm * came_norm[:, None])
            logits = logits * np.minimum(np.maximum(1.0 + cos, 0.0), 1.0)
        cur = candidates.take(first_of_row + logits.argmax(axis=1))
        step = out[:, i] = pts.take(cur, axis=0)
    return torch.from_numpy(out)


class CurveAggregation(nn.Module):
    """Adds what the curves say to every point: x (B, N, C), curves (B, count, length, C) -> (B, N, C)."""

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
        w = self.weight.last(curves)  # (B, count, length, 1)
        per_curve = (curves * torch.softmax(w, dim=2)).sum(dim=2)  # (B, count, C): each curve summarized
        per_step = (curves * torch.softmax(w, dim=1)).sum(dim=1)  # (B, length, C): each step across curves
        k_across, k_along = self.key_across.last(per_curve), self.key_along.last(per_step)  # (B, count|length, mid)
        q = self.query.last(x)  # (B, N, mid)
        att_across = torch.softmax(q @ k_across.transpose(1, 2), dim=-1)  # (B, N, count)
        # (B, length, N), the softmax over dim 1: over a short last dim (5 steps) torch's CPU softmax is
        # ~6x slower (0.107 against 0.018 ms with its product for 1024 points, 8 channels, one core)
        att_along = torch.softmax(k_along @ q.transpose(1, 2), dim=1)
        got_across = att_across @ self.value_across.last(k_across)  # (B, N, mid)
        got_along = att_along.transpose(1, 2) @ self.value_along.last(k_along)
        return F.leaky_relu_(self.out.last(torch.cat([got_across, got_along], dim=-1)).add_(x), SLOPE)


class CIC(nn.Module):
    """Curve intervention convolution: (xyz (B, N, 3), x (B, N, C_in)) -> (xyz (B, M, 3), (B, M, C_out), kNN).

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
        block's points, features and their neighbours. One kNN per resolution: the next block on the
        same points reuses it, and so does the down-sampling's ball query (its centres are among these
        points)."""
        if idx is None:
            idx = knn(xyz, self.k + 1)  # nearest first: column 0 is the point itself
        if self.points is not None and self.points < xyz.shape[1]:
            xyz, x = self._pool(xyz, x, idx)
            idx = knn(xyz, self.k + 1)
        y = sequential_last(self.reduce, x)
        if self.grouping is not None and self.aggregation is not None:
            curves, y = self.grouping(y, idx[..., 1:])
            y = self.aggregation(y, curves)
        y = self.expand.last(self.lpfa(y, xyz, idx[..., : self.k]))
        shortcut = x if isinstance(self.shortcut, nn.Identity) else self.shortcut.last(x)
        return xyz, F.leaky_relu_(y.add_(shortcut), SLOPE), idx  # y: made here, free to overwrite

    def _pool(self, xyz: torch.Tensor, x: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        chosen = farthest_point_sample(xyz, self.points)  # (B, M)
        ball = ball_from_neighbours(xyz, chosen, idx, self.radius, self.k)  # (B, M, k)
        return gather_points(xyz, chosen), max_over_neighbours(gather_points(x, ball))
