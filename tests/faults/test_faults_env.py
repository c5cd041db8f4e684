"""Faults at the environment's inputs, on the real simulators (Allegro, a box, 2 envs; issue 10, points 2 and 7).

* a NaN or inf in one env's action row (wrist or joint part) ends that env's episode ``unstable``; nothing
  non-finite reaches the env's state or the backend, the other envs step exactly as without it, the log counts it;
* a wrongly shaped or non-numeric action is one ArrayError naming the (num_envs, num_actions) layout, raised
  before anything reaches the simulator;
* ``reset_envs`` with bad env ids is one ConfigError (an int list, tuple, numpy or torch int array is accepted);
* after ``close()`` every call is one SimulationError saying the environment is closed.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers_env import build_grasp_env

from ges_core.env.gym_env import GraspGymEnv
from ges_core.env.success import EndReason
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import ArrayError, ConfigError, SimulationError

pytestmark = pytest.mark.sim
N = 2
SIMS = ["sapien", "pybullet"]
A = 16 + 6
"""Actions of the Allegro hand: 6 wrist values, then 16 joints."""
BAD_STEP = 2
"""The step (0-based) where env 1 gets the bad row."""


class _Recording:
    """A real backend that records every command that reaches it (names, in order)."""

    def __init__(self, sim) -> None:
        self._sim, self.calls = sim, []

    def __getattr__(self, name: str):
        return getattr(self._sim, name)

    def set_wrist_targets(self, pose) -> None:
        self.calls.append("set_wrist_targets")
        self._sim.set_wrist_targets(pose)

    def set_joint_targets(self, q) -> None:
        self.calls.append("set_joint_targets")
        self._sim.set_joint_targets(q)

    def step(self, n: int = 1) -> None:
        self.calls.append("step")
        self._sim.step(n)


def _venv(sim_name: str, **kw) -> GraspVecEnv:
    return GraspVecEnv(build_grasp_env(sim_name, N, reach_steps=0, settle_steps=2, **kw), seed=0)


def _actions(steps: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(7)
    return torch.rand(steps, N, A, generator=gen) * 2 - 1


def _run(sim_name: str, actions: torch.Tensor) -> tuple[list, GraspVecEnv]:
    venv = _venv(sim_name, sim_wrapper=_Recording)
    out = [venv.step(a) for a in actions]
    return out, venv


# -- non-finite actions ---------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [(0, np.nan), (3, np.nan), (A - 1, np.nan), (4, np.inf), (10, -np.inf)])
@pytest.mark.parametrize("sim_name", SIMS)
def test_non_finite_action_ends_that_env_unstable(sim_name: str, bad: tuple[int, float]) -> None:
    """A NaN or inf at a wrist entry (0, 3, 4) or a joint entry (10, 21) of env 1's row: env 1 ends unstable and
    restarts, env 0 steps bit-identically to a run where env 1 got a finite row, the log counts one bad action."""
    column, value = bad
    actions = _actions(5)
    poisoned = actions.clone()
    poisoned[BAD_STEP, 1, column] = value
    clean, clean_venv = _run(sim_name, actions)
    got, venv = _run(sim_name, poisoned)
    env = venv.env
    for t, ((obs, rew, _, extras), (obs_c, rew_c, _, extras_c)) in enumerate(zip(got, clean, strict=True)):
        assert torch.equal(obs["policy"][0], obs_c["policy"][0]), f"env 0's observation differs at step {t}"
        assert torch.equal(rew[0], rew_c[0]) and extras["end_reason"][0] == extras_c["end_reason"][0]
        assert torch.isfinite(obs["policy"]).all()
        want = 1.0 if t == BAD_STEP else 0.0
        assert extras["log"]["/faults/nan_actions"].item() == want
    _, rew, done, extras = got[BAD_STEP]
    assert extras["end_reason"].tolist() == [EndReason.RUNNING, EndReason.UNSTABLE]
    assert done.tolist() == [0, 1] and rew[1].item() == 0.0 and extras["log"]["/end/unstable"].item() == 1.0
    assert venv.episode_length_buf.tolist() == [5, 5 - BAD_STEP - 1]
    assert np.isfinite(env.wrist_target).all() and np.isfinite(env.prev_action).all()
    assert venv.fault_counts == {"nan_actions": 1} and clean_venv.fault_counts == {"nan_actions": 0}
    for v in (venv, clean_venv):
        v.close()


@pytest.mark.parametrize("sim_name", SIMS)
def test_bad_row_keeps_its_targets(sim_name: str) -> None:
    """The env with the bad row keeps the wrist and joint targets it had (the backend never sees the row)."""
    venv = _venv(sim_name)
    env = venv.env
    venv.step(_actions(1)[0])
    wrist, joints = env.wrist_target.copy(), env.joint_target.copy()
    action = _actions(2)[1]
    action[1, :] = np.nan
    env.apply_action(action)
    assert np.array_equal(env.wrist_target[1], wrist[1]) and np.array_equal(env.joint_target[1], joints[1])
    assert not np.array_equal(env.wrist_target[0], wrist[0])
    assert env.prev_action[1].tolist() == [0.0] * A
    venv.close()


@pytest.mark.parametrize("sim_name", SIMS)
def test_gym_nan_action_terminates_unstable(sim_name: str) -> None:
    gym_env = GraspGymEnv(build_grasp_env(sim_name, 1, reach_steps=0, settle_steps=2))
    gym_env.reset(seed=0)
    gym_env.step(np.zeros(A, dtype=np.float32))
    action = np.zeros(A, dtype=np.float32)
    action[2] = np.nan
    obs, reward, terminated, truncated, info = gym_env.step(action)
    assert (terminated, truncated, reward) == (True, False, 0.0)
    assert info["end_reason"] == "unstable" and info["nan_action"] is True and np.isfinite(obs).all()
    gym_env.reset()
    _, _, terminated, _, info = gym_env.step(np.zeros(A, dtype=np.float32))
    assert not terminated and info["nan_action"] is False
    gym_env.close()


# -- wrongly shaped actions ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "action",
    [
        torch.zeros(N, A - 1),
        torch.zeros(N, A + 1),  # used to send the wrist targets, then fail on the joints
        torch.zeros(N + 1, A),
        torch.zeros(A),
        torch.zeros(N, A, 1),
        np.full((N, A), "x"),
        [[0.0] * A, [0.0] * (A - 1)],
    ],
    ids=["short", "long", "rows", "1d", "3d", "strings", "ragged"],
)
@pytest.mark.parametrize("sim_name", SIMS)
def test_wrong_action_is_one_array_error_before_the_simulator(sim_name: str, action) -> None:
    venv = _venv(sim_name, sim_wrapper=_Recording)
    env, sim = venv.env, venv.env.sim
    before, steps, calls = env.wrist_target.copy(), venv.episode_length_buf.clone(), len(sim.calls)
    with pytest.raises(
        ArrayError, match=r"GraspVecEnv.step: actions (has shape|must be a numeric array of shape).*\(2, 22\).*6 wrist"
    ):
        venv.step(action)
    assert len(sim.calls) == calls and np.array_equal(env.wrist_target, before)
    assert torch.equal(venv.episode_length_buf, steps)
    venv.step(torch.zeros(N, A))  # still usable
    venv.close()


def test_gym_non_numeric_action_is_an_array_error() -> None:
    gym_env = GraspGymEnv(build_grasp_env("pybullet", 1, reach_steps=0, settle_steps=0))
    gym_env.reset(seed=0)
    with pytest.raises(ArrayError, match=r"GraspGymEnv.step: action must be a numeric array of shape \(22,\)"):
        gym_env.step(np.full(A, "x"))
    gym_env.step(np.zeros(A, dtype=np.float32))  # still usable
    gym_env.close()


def test_grasp_env_apply_action_names_itself() -> None:
    env = build_grasp_env("pybullet", N, reach_steps=0, settle_steps=0)
    env.reset_all()
    with pytest.raises(ArrayError, match=r"GraspEnv.apply_action: action has shape \(2, 21\), expected \(2, 22\)"):
        env.apply_action(torch.zeros(N, A - 1))
    env.close()


# -- reset_envs ids --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("ids", "message"),
    [
        (torch.tensor([2]), r"out of range for num_envs=2"),
        ([-1], r"out of range"),
        (torch.tensor([0.0]), r"1-D sequence of integer env indices"),
        ([0.5], r"1-D sequence of integer env indices"),
        (torch.tensor([True, False]), r"boolean mask m gives indices with m.nonzero"),
        ([1, 1], r"repeat \[1\]"),
        (torch.tensor([[0]]), r"1-D sequence"),
        (1, r"1-D sequence"),
    ],
    ids=["range", "negative", "float-tensor", "float-list", "mask", "repeat", "2d", "scalar"],
)
@pytest.mark.parametrize("sim_name", SIMS)
def test_reset_envs_bad_ids_is_one_config_error(sim_name: str, ids, message: str) -> None:
    venv = _venv(sim_name)
    with pytest.raises(ConfigError, match=r"GraspEnv.reset_envs: .*" + message):
        venv.env.reset_envs(ids)
    venv.close()


@pytest.mark.parametrize("sim_name", SIMS)
def test_reset_envs_accepts_int_sequences(sim_name: str) -> None:
    """Each accepted form resets env 1 (and only it); an empty one resets nothing. Stepping before each reset
    makes every call show its effect: an id list read as empty would leave env 1's last action in place."""
    venv = _venv(sim_name)
    env = venv.env
    q_start = env.start_state(torch.tensor([1]))[0].numpy()[0]
    forms = [[1], (1,), np.array([1]), torch.tensor([1], dtype=torch.int32), [], torch.tensor([], dtype=torch.long)]
    for ids, action in zip(forms, _actions(len(forms)), strict=True):
        venv.step(action)
        assert (env.prev_action != 0).any(axis=1).all()  # both envs moved on from their start
        env.reset_envs(ids)
        reset = len(ids) > 0
        assert bool((env.prev_action[1] == 0).all()) is reset, f"reset_envs({ids!r})"
        assert np.array_equal(env.joint_target[1], q_start) is reset, f"reset_envs({ids!r})"
        assert (env.prev_action[0] != 0).any()  # env 0 untouched
    venv.close()


# -- after close() --------------------------------------------------------------------------------
CLOSED = r"the environment is closed; build a new one"


@pytest.mark.parametrize("sim_name", SIMS)
def test_vec_env_after_close_raises(sim_name: str) -> None:
    venv = _venv(sim_name)
    venv.close()
    venv.close()  # twice is harmless
    with pytest.raises(SimulationError, match=r"GraspVecEnv.get_observations: " + CLOSED):
        venv.get_observations()
    with pytest.raises(SimulationError, match=r"GraspVecEnv.step: " + CLOSED):
        venv.step(torch.zeros(N, A))
    env = venv.env
    calls = [
        ("reset_all", lambda: env.reset_all()),
        ("reset_envs", lambda: env.reset_envs([0])),
        ("apply_action", lambda: env.apply_action(torch.zeros(N, A))),
        ("observe", lambda: env.observe()),
    ]
    for name, call in calls:
        with pytest.raises(SimulationError, match=rf"GraspEnv.{name}: " + CLOSED):
            call()


@pytest.mark.parametrize("sim_name", SIMS)
def test_closing_the_backend_closes_the_env(sim_name: str) -> None:
    """Closing the backend directly (``env.sim.close()``) counts too: no stale observation."""
    venv = _venv(sim_name)
    venv.env.sim.close()
    with pytest.raises(SimulationError, match=CLOSED):
        venv.get_observations()
    venv.close()


@pytest.mark.parametrize("sim_name", SIMS)
def test_gym_env_after_close_raises(sim_name: str) -> None:
    gym_env = GraspGymEnv(build_grasp_env(sim_name, 1, reach_steps=0, settle_steps=0))
    gym_env.reset(seed=0)
    gym_env.close()
    gym_env.close()
    with pytest.raises(SimulationError, match=r"GraspGymEnv.step: " + CLOSED):
        gym_env.step(np.zeros(A, dtype=np.float32))
    with pytest.raises(SimulationError, match=r"GraspGymEnv.reset: " + CLOSED):
        gym_env.reset()
