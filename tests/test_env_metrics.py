"""Table 3 metrics of ges_core.env.metrics against closed forms and plain-Python loops."""

from __future__ import annotations

import pytest
import torch
from helpers_env import build_grasp_env

from ges_core.env.metrics import EpisodeMetrics, finger_directional_consistency, oscillation
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import ConfigError

DT = 1 / 60
GROUPS = torch.tensor([[0, 2, 4], [1, 3, 5]])  # two joint positions of three fingers; joint 6 is a "thumb"
K = 7


def _loop_oscillation(vel: list[list[float]], dt: float) -> float:
    """Σ_t Σ_d (v[t][d] − v[t−1][d])² / dt, written out."""
    total = 0.0
    for t in range(1, len(vel)):
        for d in range(len(vel[t])):
            total += (vel[t][d] - vel[t - 1][d]) ** 2 / dt
    return total


def _sign(x: float) -> float:
    return (x > 0) - (x < 0)


def _loop_fdc(vel: list[list[float]], groups: list[list[int]]) -> float:
    """−Σ_t Σ_j population variance of the signs of row j's joints, written out."""
    total = 0.0
    for row in vel:
        for group in groups:
            signs = [_sign(row[i]) for i in group]
            mean = sum(signs) / len(signs)
            total -= sum((s - mean) ** 2 for s in signs) / len(signs)
    return total


def _run(metrics: EpisodeMetrics, joint: torch.Tensor, wrist: torch.Tensor) -> dict[str, torch.Tensor]:
    """Feed (T, n, ·) trajectories step by step and read every env."""
    for t in range(joint.shape[0]):
        metrics.update(joint[t], wrist[t])
    return metrics.read(torch.arange(joint.shape[1]))


def test_constant_velocity_has_zero_oscillation() -> None:
    steps, n = 30, 2
    joint = torch.tensor([0.7, -0.3, 0.1, 2.0, -1.0, 0.4, 0.0]).expand(steps, n, K)
    wrist = torch.tensor([0.1, 0.0, -0.2, 0.5, 0.5, 0.0]).expand(steps, n, 6)
    out = _run(EpisodeMetrics(n, GROUPS, DT), joint, wrist)
    assert torch.equal(out["arm_oscillation"], torch.zeros(n, dtype=torch.float64))
    assert torch.equal(out["hand_oscillation"], torch.zeros(n, dtype=torch.float64))
    assert out["steps"].tolist() == [steps] * n


def test_alternating_velocity_matches_closed_form() -> None:
    # v_t = (-1)^t a: every difference is ±2a on each of D dims, so T − 1 differences give (T − 1) D 4a² / dt
    steps, a = 25, 0.3
    signs = torch.tensor([(-1.0) ** t for t in range(steps)], dtype=torch.float64)
    joint = (signs * a)[:, None, None].expand(steps, 1, K)
    wrist = (signs * 2 * a)[:, None, None].expand(steps, 1, 6)
    out = _run(EpisodeMetrics(1, GROUPS, DT), joint, wrist)
    assert out["hand_oscillation"].item() == pytest.approx((steps - 1) * K * 4 * a**2 / DT)
    assert out["arm_oscillation"].item() == pytest.approx((steps - 1) * 6 * 4 * (2 * a) ** 2 / DT)


def test_fingers_together_give_fdc_zero_and_opposed_negative() -> None:
    steps = 10
    together = torch.tensor([1.0, -2.0, 0.5, -1.0, 3.0, -0.1, -5.0]).expand(steps, 1, K)
    # position 0: signs (+, -, +) -> variance 8/9; position 1: (+, +, -) -> 8/9
    opposed = torch.tensor([1.0, 2.0, -0.5, 1.0, 3.0, -0.1, -5.0]).expand(steps, 1, K)
    zero = torch.zeros(steps, 1, 6)
    m = EpisodeMetrics(1, GROUPS, DT)
    assert _run(m, together, zero)["fdc"].item() == 0.0
    m.reset(torch.tensor([0]))
    assert _run(m, opposed, zero)["fdc"].item() == pytest.approx(-steps * 2 * 8 / 9)


def test_batched_accumulator_equals_per_env_loops_with_resets() -> None:
    gen = torch.Generator().manual_seed(0)
    steps, n = 40, 3
    joint = torch.randn(steps, n, K, generator=gen, dtype=torch.float64)
    wrist = torch.randn(steps, n, 6, generator=gen, dtype=torch.float64)
    m = EpisodeMetrics(n, GROUPS, DT)
    cut = 17  # env 1 starts a new episode at step `cut`
    for t in range(steps):
        if t == cut:
            m.reset(torch.tensor([1]))
        m.update(joint[t], wrist[t])
    out = m.read(torch.arange(n))
    groups = GROUPS.tolist()
    for i in range(n):
        first = cut if i == 1 else 0
        jl, wl = joint[first:, i].tolist(), wrist[first:, i].tolist()
        assert out["hand_oscillation"][i].item() == pytest.approx(_loop_oscillation(jl, DT))
        assert out["arm_oscillation"][i].item() == pytest.approx(_loop_oscillation(wl, DT))
        assert out["fdc"][i].item() == pytest.approx(_loop_fdc(jl, groups))
        assert out["steps"][i].item() == steps - first
    # the whole-trajectory functions agree with the accumulator
    assert torch.allclose(out["hand_oscillation"][[0, 2]], oscillation(joint, DT)[[0, 2]])
    assert torch.allclose(out["fdc"][[0, 2]], finger_directional_consistency(joint, GROUPS)[[0, 2]])


def test_masked_and_non_finite_steps_are_skipped() -> None:
    m = EpisodeMetrics(2, GROUPS, DT)
    ones, zero = torch.ones(2, K), torch.zeros(2, 6)
    m.update(ones, zero)
    bad = ones.clone()
    bad[1, 0] = float("nan")
    m.update(-ones, zero, mask=torch.tensor([False, True]))  # env 0 masked out
    m.update(bad, zero)  # env 1 not finite: skipped
    out = m.read(torch.arange(2))
    # env 0 saw +1, (skip), +1: no change; env 1 saw +1, −1 (jump of 2 on K joints), (skip)
    assert out["steps"].tolist() == [2, 2]
    assert out["hand_oscillation"].tolist() == pytest.approx([0.0, K * 4 / DT])
    assert torch.isfinite(out["fdc"]).all()


def test_bad_dt_is_rejected() -> None:
    with pytest.raises(ConfigError, match="control step must be > 0"):
        EpisodeMetrics(1, GROUPS, 0.0)


@pytest.mark.sim
def test_vec_env_logs_the_metrics_of_ended_episodes() -> None:
    env = build_grasp_env("sapien", 2, reach_steps=5, settle_steps=2, episode_length=4)
    states, observe = [], env.observe

    def recording_observe(**kw):  # noise_rows: GraspVecEnv passes it through
        obs, state = observe(**kw)
        states.append(state)
        return obs, state

    env.observe = recording_observe
    venv = GraspVecEnv(env)
    states.clear()
    gen = torch.Generator().manual_seed(0)
    for t in range(4):
        td, _, done, extras = venv.step(torch.rand(2, venv.num_actions, generator=gen) * 2 - 1)
        if t < 3:  # the policy sees the step's own wrist velocity (not a zero from a second observe)
            assert torch.allclose(env.obs_layout.unpack(td["policy"], "wrist_vel"), states[-1]["wrist_vel"].float())
            assert not any(key.startswith("/metrics/") for key in extras["log"])
    env.sim.close()
    assert done.tolist() == [1, 1]
    steps = states[:4]  # one observe per step, then one after the reset
    assert len(states) == 5
    groups = env.groups.tolist()
    for name, vel, loop in (
        ("hand_oscillation", "dq", lambda v: _loop_oscillation(v, env.control_dt)),
        ("arm_oscillation", "wrist_vel", lambda v: _loop_oscillation(v, env.control_dt)),
        ("fdc", "dq", lambda v: _loop_fdc(v, groups)),
    ):
        per_env = [loop([s[vel][i].tolist() for s in steps]) for i in range(2)]
        assert extras["log"][f"/metrics/{name}"].item() == pytest.approx(sum(per_env) / 2)
    assert venv.metrics.steps.tolist() == [0, 0]  # reset with the episodes
