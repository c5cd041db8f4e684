"""The gate networks' fast inference path against the direct formulas (issue 14, gate speed).

CurveNet and PointNet++ compute their layers channels-last, split linear maps of concatenations into
per-point parts, walk the curves in numpy at CPU inference and reuse one kNN per resolution
(benchmarks/gate_speed.py). The references here are the direct, channels-first versions those replaced
(torch.gather, a 1x1 convolution on the concatenated geometry / pair / group, the curve walk with its
straight-through choice at every step, a ball query of its own), run on the same modules' weights, on
random clouds with random BatchNorm statistics, in eval and in train mode.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ges_core.gating.layers import ConvBN
from ges_core.gating.ops import (
    _fps_numpy,
    ball_from_neighbours,
    ball_query,
    farthest_point_sample,
    gather_points,
    knn,
    max_over_neighbours,
)
from ges_plugins.gates.curvenet.model import CurveNet
from ges_plugins.gates.pointnet2.model import PointNet2

SLOPE = 0.2
CURVENET = {
    "k": 8,
    "stem": 8,
    "stages": [
        {"channels": 16, "points": None, "radius": 0.3, "curves": (8, 4)},
        {"channels": 32, "points": 64, "radius": 0.5, "curves": (6, 3)},
        {"channels": 32, "points": 16, "radius": 1.0, "curves": None},
    ],
    "embed": 32,
    "head": [16],
    "dropout": 0.0,  # train-mode comparisons run the network twice: no random masks
}
POINTNET2 = {
    "levels": [
        {"centres": 64, "radius": 0.3, "group": 8, "mlp": [16, 16]},
        {"centres": 16, "radius": 0.6, "group": 12, "mlp": [16, 32]},
    ],
    "global_mlp": [32, 48],
    "head": [16],
    "dropout": 0.0,
}


def clouds(seed: int, batch: int = 3, n: int = 256) -> torch.Tensor:
    """(batch, n, 3) random clouds spanning ~2 network units (a 20 cm object at input_scale 0.1 m)."""
    return torch.rand(batch, n, 3, generator=torch.Generator().manual_seed(seed)) * 2.0


def randomized(model: torch.nn.Module, seed: int) -> torch.nn.Module:
    """model with random BatchNorm statistics and affine parameters (fresh ones would fold to identity)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.3)
                m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.weight.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.bias.copy_(torch.randn(m.num_features, generator=gen) * 0.3)
    return model


# -- the direct formulas (the channels-first code the fast path replaced) ----------------------------------
def ref_gather(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """(B, N, C) rows at idx (B, ...) by torch.gather with the index expanded over the channels."""
    flat = idx.reshape(values.shape[0], -1)
    out = torch.gather(values, 1, flat.unsqueeze(-1).expand(-1, -1, values.shape[-1]))
    return out.reshape(*idx.shape, values.shape[-1])


def ref_neighbours(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """features (B, C, N) at idx (B, ...) -> (B, C, ...)."""
    return ref_gather(features.transpose(1, 2), idx).movedim(-1, 1)


def ref_lpfa(m, x: torch.Tensor | None, xyz: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """LPFA on (B, C, N) features: the 9-d geometry (p_i, p_j, p_j - p_i) of every pair through the layer."""
    centre = xyz.unsqueeze(2).expand(-1, -1, idx.shape[-1], -1)
    neighbour = ref_gather(xyz, idx)
    geometry = torch.cat([centre, neighbour, neighbour - centre], dim=-1).permute(0, 3, 1, 2)  # (B, 9, N, k)
    if m.stem:
        return m.mlp(geometry).max(dim=-1).values
    local = F.leaky_relu(ref_neighbours(x, idx) - x.unsqueeze(-1) + m.geometry(geometry), SLOPE)
    return m.mlp(local).mean(dim=-1)


def ref_grouping(m, x: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The curve walk on (B, C, N): the policy on each (candidate, descriptor) pair, the momentum on
    (step, descriptor), a straight-through choice every step; curves (B, C, count, length)."""
    score = torch.sigmoid(m.start(x))
    x = x * score
    current = score.squeeze(1).topk(min(m.count, x.shape[-1]), dim=-1).indices
    descriptor = ref_neighbours(x, current)
    step, steps = None, []
    for _ in range(m.length):
        if step is not None:
            w = torch.softmax(m.momentum(torch.cat([step, descriptor], dim=1)), dim=1)
            descriptor = w[:, :1] * step + w[:, 1:] * descriptor
        candidates = ref_gather(idx, current)
        cand = ref_neighbours(x, candidates)  # (B, C, count, k)
        logits = m.policy(torch.cat([cand, descriptor.unsqueeze(-1).expand_as(cand)], dim=1)).squeeze(1)
        if step is not None:
            with torch.no_grad():
                came, go = (step - descriptor).unsqueeze(-1), cand - step.unsqueeze(-1)
                damp = (1.0 + F.cosine_similarity(came, go, dim=1, eps=1e-8)).clamp(0.0, 1.0)
            logits = logits * damp
        soft = torch.softmax(logits, dim=-1)
        choice = F.one_hot(soft.argmax(dim=-1), soft.shape[-1]).to(soft.dtype) + soft - soft.detach()
        step = (cand * choice.unsqueeze(1)).sum(dim=-1)
        current = torch.gather(candidates, -1, choice.argmax(dim=-1, keepdim=True)).squeeze(-1)
        steps.append(step)
    return torch.stack(steps, dim=-1), x


def ref_aggregation(m, x: torch.Tensor, curves: torch.Tensor) -> torch.Tensor:
    w = m.weight(curves)
    per_curve = (curves * torch.softmax(w, dim=-1)).sum(dim=-1)
    per_step = (curves * torch.softmax(w, dim=-2)).sum(dim=-2)
    k_across, k_along = m.key_across(per_curve), m.key_along(per_step)
    q = m.query(x).transpose(1, 2)
    got_across = torch.softmax(q @ k_across, dim=-1) @ m.value_across(k_across).transpose(1, 2)
    got_along = torch.softmax(q @ k_along, dim=-1) @ m.value_along(k_along).transpose(1, 2)
    return F.leaky_relu(x + m.out(torch.cat([got_across, got_along], dim=-1).transpose(1, 2)), SLOPE)


def ref_cic(m, xyz: torch.Tensor, x: torch.Tensor, idx: torch.Tensor | None):
    if m.points is not None and m.points < xyz.shape[1]:
        centres = ref_gather(xyz, farthest_point_sample(xyz, m.points))
        ball = ball_query(xyz, centres, m.radius, m.k)  # a search of its own
        xyz, x, idx = centres, ref_neighbours(x, ball).max(dim=-1).values, None
    if idx is None:
        idx = knn(xyz, m.k + 1)
    y = m.reduce(x)
    if m.grouping is not None:
        curves, y = ref_grouping(m.grouping, y, idx[..., 1:])
        y = ref_aggregation(m.aggregation, y, curves)
    y = m.expand(ref_lpfa(m.lpfa, y, xyz, idx[..., : m.k]))
    return xyz, F.leaky_relu(y + m.shortcut(x), SLOPE), idx


def ref_curvenet(model: CurveNet, xyz: torch.Tensor) -> torch.Tensor:
    idx = knn(xyz, model.k + 1)
    x = ref_lpfa(model.stem, None, xyz, idx[..., : model.k])
    for block in model.blocks:
        xyz, x, idx = ref_cic(block, xyz, x, idx)
    x = model.embed(x)
    return model.head(torch.cat([F.adaptive_max_pool1d(x, 1), F.adaptive_avg_pool1d(x, 1)], dim=1).squeeze(-1))


def ref_set_abstraction(m, xyz: torch.Tensor, features: torch.Tensor | None):
    """A PointNet++ level: the shared MLP on every (offset / radius, features) row of every group."""
    if m.centres is None:
        new_xyz, grouped = xyz.new_zeros(xyz.shape[0], 1, 3), xyz.unsqueeze(1)
        feats = None if features is None else features.unsqueeze(1)
    else:
        new_xyz = ref_gather(xyz, farthest_point_sample(xyz, m.centres))
        idx = ball_query(xyz, new_xyz, m.radius, m.group)
        grouped = (ref_gather(xyz, idx) - new_xyz.unsqueeze(2)) / m.radius
        feats = None if features is None else ref_gather(features, idx)
    x = grouped if feats is None else torch.cat([grouped, feats], dim=-1)
    return new_xyz, m.mlp(x.permute(0, 3, 1, 2)).max(dim=-1).values.transpose(1, 2)


def ref_pointnet2(model: PointNet2, xyz: torch.Tensor) -> torch.Tensor:
    features = None
    for level in model.levels:
        xyz, features = ref_set_abstraction(level, xyz, features)
    return model.head(ref_set_abstraction(model.pool, xyz, features)[1].squeeze(1))


def ref_fps(points: np.ndarray, m: int) -> np.ndarray:
    """Greedy farthest points from the point farthest from the centroid, one coordinate array at a time."""
    x, y, z = (points[:, i].copy() for i in range(3))
    centre = points.mean(axis=0)
    current = int((((x - centre[0]) ** 2 + (y - centre[1]) ** 2) + (z - centre[2]) ** 2).argmax())
    dist, chosen = np.full(len(points), np.inf, dtype=points.dtype), []
    for _ in range(m):
        chosen.append(current)
        dx, dy, dz = x - x[current], y - y[current], z - z[current]
        dist = np.minimum(dist, (dx * dx + dy * dy) + dz * dz)
        current = int(dist.argmax())
    return np.array(chosen)


NETWORKS = {
    "curvenet": (lambda: CurveNet(3, **CURVENET), ref_curvenet),
    "pointnet2": (
        lambda: PointNet2(3, POINTNET2["levels"], POINTNET2["global_mlp"], POINTNET2["head"], 0.0),
        ref_pointnet2,
    ),
}


def network(name: str, seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    return randomized(NETWORKS[name][0](), seed)


# -- point operations --------------------------------------------------------------------------------------
def test_gather_points_is_torch_gather():
    gen = torch.Generator().manual_seed(0)
    values = torch.randn(3, 50, 7, generator=gen)
    idx = torch.randint(0, 50, (3, 20, 4), generator=gen)
    assert torch.equal(gather_points(values, idx), ref_gather(values, idx))
    ints = torch.randint(0, 50, (3, 50, 5), generator=gen)  # neighbour lists are gathered too
    assert torch.equal(gather_points(ints, idx[..., 0]), ref_gather(ints, idx[..., 0]))


@pytest.mark.parametrize("channels", [4, 16, 31, 32, 64])
def test_max_over_neighbours_both_ways(channels):
    x = torch.randn(2, 30, 7, channels, generator=torch.Generator().manual_seed(channels))
    assert torch.equal(max_over_neighbours(x), x.max(dim=2).values)


def test_numpy_farthest_points_match_the_reference_loop():
    for seed in range(5):
        points = np.random.default_rng(seed).random((300, 3)).astype(np.float32) * 2.0
        assert np.array_equal(_fps_numpy(points, 40), ref_fps(points, 40))


def test_ball_from_a_known_knn_is_the_ball_query_and_within_the_radius():
    xyz = clouds(1, batch=2, n=300)
    neighbours = knn(xyz, 9)
    centre_idx = farthest_point_sample(xyz, 40)
    centres = gather_points(xyz, centre_idx)
    for radius in (0.15, 0.3, 5.0):  # most balls short, some, none
        ball = ball_from_neighbours(xyz, centre_idx, neighbours, radius, 8)
        assert torch.equal(ball, ball_query(xyz, centres, radius, 8))
        d = torch.cdist(centres, xyz)  # brute force: members within the radius, and the nearest ones
        member_d = torch.gather(d, 2, ball)
        assert (member_d <= radius + 1e-6).all()
        inside = (d <= radius).sum(-1).clamp(max=8)
        distinct = torch.tensor([[len(set(row.tolist())) for row in b] for b in ball])
        assert torch.equal(distinct, inside.clamp(min=1))
    with pytest.raises(ValueError, match="9 neighbours known, 12 asked"):
        ball_from_neighbours(xyz, centre_idx, neighbours, 0.3, 12)


# -- the networks against the direct formulas --------------------------------------------------------------
@pytest.mark.parametrize("name", list(NETWORKS))
def test_eval_output_matches_the_direct_formulas(name):
    """Inference (no gradients: the numpy walk, cached folds) and eval with gradients (the torch walk)."""
    model, ref = network(name, 1).eval(), NETWORKS[name][1]
    for seed in (2, 3):
        xyz = clouds(seed)
        with torch.no_grad():
            expected = ref(model, xyz)
            fast = model(xyz)
        with torch.inference_mode():
            inferred = model(xyz)
        with torch.enable_grad():
            graded = model(xyz)
        scale = expected.abs().max()
        assert scale > 0.1  # a real signal, not everything folded to ~0
        for out in (fast, inferred, graded.detach()):
            assert torch.allclose(out, expected, atol=1e-5 * scale, rtol=1e-4), (out - expected).abs().max()


@pytest.mark.parametrize("name", list(NETWORKS))
def test_train_mode_output_and_gradients_match_the_direct_formulas(name):
    """Batch statistics, the straight-through walk and the split layers' gradients (float64)."""
    model, ref = network(name, 4).train().double(), NETWORKS[name][1]
    twin = copy.deepcopy(model)
    xyz = clouds(5).double()
    out, expected = model(xyz), ref(twin, xyz)
    assert torch.allclose(out, expected, atol=1e-9), (out - expected).abs().max()
    weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    (out * weights).sum().backward()
    (expected * weights).sum().backward()
    twin_params = dict(twin.named_parameters())
    for key, p in model.named_parameters():
        g, g_ref = p.grad, twin_params[key].grad
        assert g is not None and g_ref is not None, key
        assert torch.allclose(g, g_ref, atol=1e-9 * (1 + g_ref.abs().max())), key
    for key, buf in model.named_buffers():  # running statistics updated alike
        assert torch.allclose(buf.double(), dict(twin.named_buffers())[key].double(), atol=1e-9), key


def test_curvenet_walks_agree_in_numpy_and_torch():
    """The numpy walk (inference) and the torch walk (eval with gradients) pick the same curves."""
    model = network("curvenet", 7).eval()
    grouping, xyz = model.blocks[0].grouping, clouds(8, batch=2, n=200)
    idx = knn(xyz, model.k + 1)[..., 1:]
    x = torch.randn(2, 200, grouping.start.weight.shape[1], generator=torch.Generator().manual_seed(9))
    with torch.no_grad():
        numpy_curves, _ = grouping(x, idx)
    with torch.enable_grad():
        torch_curves, _ = grouping(x, idx)
    assert numpy_curves.shape == (2, 8, 4, x.shape[-1])
    assert torch.allclose(numpy_curves, torch_curves.detach(), atol=1e-5)


def test_folded_batchnorm_follows_every_change_of_the_layer():
    torch.manual_seed(0)
    layer, other = randomized(ConvBN(4, 3), 1).eval(), randomized(ConvBN(4, 3), 2).eval()
    x = torch.randn(2, 4, 5)

    def both() -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            cached = layer(x)
        with torch.enable_grad():  # not cached: folded anew
            return cached, layer(x).detach()

    first, fresh = both()
    assert torch.allclose(first, fresh, atol=1e-6)
    with torch.no_grad():
        layer.bn.running_mean.add_(0.5)  # an in-place change
    changed, fresh = both()
    assert not torch.allclose(changed, first) and torch.allclose(changed, fresh, atol=1e-6)
    layer.load_state_dict(other.state_dict())
    loaded, _ = both()
    assert torch.allclose(loaded, other(x), atol=1e-6)
    layer.double()
    with torch.no_grad():
        assert layer(x.double()).dtype == torch.float64


def test_derived_constants_follow_the_fold():
    """ConvBN.derived: made once at inference, made anew after a change of the layer, never kept with gradients."""
    layer = randomized(ConvBN(4, 3), 1).eval()
    calls = []

    def make(weight, bias):
        calls.append(1)
        return weight.sum(dim=1) + bias

    def expected():
        weight, bias = layer._fold()
        return weight.detach().sum(dim=1) + bias.detach()

    with torch.no_grad():
        first, again = layer.derived("sum", make), layer.derived("sum", make)
    assert len(calls) == 1 and again is first and torch.allclose(first, expected())
    with torch.no_grad():
        layer.conv.weight.mul_(2.0)  # an in-place change: the fold and what is derived from it renewed
        changed = layer.derived("sum", make)
    assert len(calls) == 2 and torch.allclose(changed, expected()) and not torch.allclose(changed, first)
    with torch.enable_grad():
        layer.derived("sum", make), layer.derived("sum", make)
    assert len(calls) == 4


def test_inference_after_loading_other_weights_matches_the_direct_formulas():
    """The cached folds and derived constants (LPFA geometry, walk policy) follow load_state_dict."""
    model, other = network("curvenet", 11).eval(), network("curvenet", 12).eval()
    xyz = clouds(13)
    with torch.inference_mode():
        before = model(xyz)  # fills the caches
    model.load_state_dict(other.state_dict())
    with torch.no_grad():
        expected = ref_curvenet(other, xyz)
    with torch.inference_mode():
        after = model(xyz)
    scale = expected.abs().max()
    assert not torch.allclose(before, after, atol=1e-3 * scale)
    assert torch.allclose(after, expected, atol=1e-5 * scale, rtol=1e-4), (after - expected).abs().max()


def test_a_prediction_is_an_ordinary_tensor():
    """predict runs under inference_mode; what it returns can still be edited and used with autograd."""
    from ges_plugins.gates.curvenet.gate import CurveNetGate

    gate = CurveNetGate(n_points=128, k=8, stem=8, stages=CURVENET["stages"], embed=32, head=[16])
    torch.manual_seed(0)
    gate.experts, gate.model = ("a", "b", "c"), gate.build_model(3).eval()
    probs = gate.predict(clouds(10, batch=2, n=128) * 0.1)
    assert not probs.is_inference()
    probs.mul_(2.0)  # in place: refused on an inference tensor
    assert torch.allclose(probs.sum(dim=1), torch.full((2,), 2.0), atol=1e-5)
