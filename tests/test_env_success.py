"""Success protocols and end reasons of ges_core.env.success."""

from __future__ import annotations

import torch

from ges_core.env.success import EndReason, SuccessConfig, SuccessTracker


def _run(heights: list[list[float]], cfg: SuccessConfig, sim_steps: int, horizon: int) -> list[list[int]]:
    n = len(heights[0])
    tr = SuccessTracker(cfg, n, sim_steps)
    tr.reset(torch.arange(n), torch.zeros(n, 3))
    out = []
    for t, row in enumerate(heights):
        pos = torch.zeros(n, 3)
        pos[:, 2] = torch.tensor(row)
        out.append(tr.update(pos, torch.full((n,), t == horizon - 1)).tolist())
    return out, tr


def test_paper_hold_counts_simulation_steps() -> None:
    cfg = SuccessConfig(hold_steps=200)
    # 4 sim steps per control step: 50 control steps at 0.2 m complete the hold, not 49
    heights = [[0.1]] + [[0.21]] * 50
    reasons, _ = _run(heights, cfg, sim_steps=4, horizon=1000)
    assert reasons[49] == [EndReason.RUNNING] and reasons[50] == [EndReason.SUCCESS]


def test_hold_restarts_when_the_object_dips() -> None:
    cfg = SuccessConfig(hold_steps=3)
    reasons, tr = _run([[0.2], [0.2], [0.19], [0.2], [0.2]], cfg, sim_steps=1, horizon=100)
    assert [r[0] for r in reasons] == [0, 0, 0, 0, 0] and tr.held.item() == 2


def test_peer_protocol_needs_no_hold_and_end_reasons() -> None:
    cfg = SuccessConfig()
    # env0: passes near the target once then drops; env1: never lifts; env2: lifted a bit, times out
    heights = [[0.0, 0.0, 0.0], [0.16, 0.001, 0.05], [0.005, 0.001, 0.05]]
    reasons, tr = _run(heights, cfg, sim_steps=1, horizon=3)
    assert tr.peer_success.tolist() == [True, False, False]
    assert reasons[1] == [0, 0, 0]
    assert reasons[2] == [EndReason.DROPPED, EndReason.NOT_LIFTED, EndReason.TIMEOUT]


def test_reset_clears_one_env_only() -> None:
    tr = SuccessTracker(SuccessConfig(), 2)
    tr.reset(torch.arange(2), torch.zeros(2, 3))
    tr.update(torch.tensor([[0.0, 0.0, 0.2], [0.0, 0.0, 0.2]]), torch.zeros(2, dtype=torch.bool))
    tr.reset(torch.tensor([1]), torch.tensor([[1.0, 0.0, 0.1]], dtype=torch.float64))
    assert tr.peer_success.tolist() == [True, False] and tr.held.tolist() == [1, 0]
    assert tr.start[1].tolist() == [1.0, 0.0, 0.1]
