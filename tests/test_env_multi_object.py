"""Multi-object GraspEnv (GraspEnv.from_pool) and per-episode randomization, on the real simulators.

Two boxes centred on their object frames (resting=False), so each rests with its origin at its own half height:
the height an env's object settles at in the simulator tells which box that env really holds.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.env.grasp_env import EnvConfig, GraspEnv
from ges_core.env.grasp_pool import GraspPool, PoolEntry
from ges_core.env.randomization import RandomizationConfig
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import AssetError, ConfigError
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.sim_check import grasp_start_pose
from ges_core.transforms import quat_to_rotvec

HALF = {"short": 0.03, "tall": 0.05}
"""Half heights (m) of the two test boxes; rested, their origins sit this high (+ the backend's 0.2 mm margin)."""


def _entry(hand, name: str) -> PoolEntry:
    """A palm-down grasp over the box's top, in the box's frame (origin at its centre), pre-grasp 2 cm up."""
    hz = HALF[name]
    box = box_asset((0.025, 0.03, hz), density=300.0, object_id=f"test/{name}", resting=False)
    pose = grasp_start_pose(hand, np.array([0.0, 0.0, 0.0]), 0.5, object_top=hz)
    pre = pose.copy()
    pre[2] += 0.02
    d = hand.description
    return PoolEntry(box, pose, np.asarray(d.closed_pose(0.5)), pre, np.asarray(d.open_pose, dtype=np.float64))


def _env(sim_name: str, n: int, weights=None, **cfg) -> GraspEnv:
    reg = load_registry()
    hand = reg.build_hand("allegro")
    pool = GraspPool([_entry(hand, "short"), _entry(hand, "tall")], weights)
    sim = reg.build_sim(sim_name, SceneConfig(num_envs=n))
    return GraspEnv.from_pool(sim, hand, pool, EnvConfig(reach_steps=4, settle_steps=2, **cfg))


def _height_says(env: GraspEnv) -> list[str]:
    """Which box each env holds, read from the simulator: the height its object rests at."""
    z = env.sim.object_pose()[:, 2]
    return ["short" if abs(h - HALF["short"]) < 0.005 else "tall" if abs(h - HALF["tall"]) < 0.005 else "?" for h in z]


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_each_env_holds_its_own_object_and_grasp(sim_name: str) -> None:
    env = _env(sim_name, 4, randomization=RandomizationConfig(seed=3))
    env.reset_all()
    env.sim.step(10)  # the objects settle under the hands (the pre-grasps are 2 cm above the tops)
    names = [o.removeprefix("test/") for o in env.object_ids]
    assert _height_says(env) == names and set(names) == {"short", "tall"}, (names, env.sim.object_pose()[:, 2])
    # each env's grasp was mapped through its own object's pose: goal wrist height = where the simulator holds
    # that env's object + the entry's height in the object frame
    entry_z = np.array([env.pool.entries[k].wrist_pose[2] for k in env.entry])
    goal_z = env.grasps["wrist_pose"][:, 2].numpy()
    assert np.allclose(goal_z, env.sim.object_pose()[:, 2] + entry_z, atol=1e-3)
    # the curriculum narrows the pool: envs restarted from now on hold only the tall box, others keep theirs
    env.pool.set_weights({"test/tall": 1.0})
    env.reset_envs([0, 1])
    env.sim.step(10)
    assert env.object_ids[:2] == ["test/tall"] * 2 and _height_says(env)[:2] == ["tall", "tall"]
    assert env.object_ids[2:] == [f"test/{n}" for n in names[2:]]
    env.close()


@pytest.mark.sim
def test_vec_env_reports_each_episodes_entry_and_restarts_from_the_pool() -> None:
    venv = GraspVecEnv(_env("sapien", 2, episode_length=3), seed=0)
    keys = venv.env.pool.keys
    for _ in range(3):
        _, _, done, extras = venv.step(torch.zeros(2, venv.num_actions))
    assert done.all() and [keys[i] for i in extras["entry"].tolist()] == [o for o in extras_objects(venv, extras)]
    venv.close()


def extras_objects(venv: GraspVecEnv, extras: dict) -> list[str]:
    """Object ids of the ended episodes, read through the entries (the env has drawn the next ones already)."""
    return [venv.env.pool.entries[i].key for i in extras["entry"].tolist()]


def test_pool_draws_follow_the_weights() -> None:
    """10,000 draws: each frequency within 0.02 of weight / sum (the binomial standard error is <= 0.005);
    a zero weight is never drawn."""
    reg = load_registry()
    hand = reg.build_hand("allegro")
    e = _entry(hand, "short")
    pool = GraspPool([e, e, e, e], [1.0, 3.0, 0.0, 6.0])
    draws = pool.draw(np.random.default_rng(0), 10_000)
    freq = np.bincount(draws, minlength=4) / len(draws)
    assert np.all(np.abs(freq - [0.1, 0.3, 0.0, 0.6]) < 0.02) and freq[2] == 0.0


@pytest.mark.sim
def test_env_draws_follow_the_pool_weights() -> None:
    """Through the environment: 300 per-env episode starts with weights 1 : 3 give the tall box 0.75 +- 0.08
    (four standard errors), and every env's simulator holds the box it drew."""
    env = _env("sapien", 2, weights=[1.0, 3.0])
    tall = 0
    for _ in range(150):
        env.reset_envs([0, 1])
        tall += sum(o == "test/tall" for o in env.object_ids)
    assert abs(tall / 300 - 0.75) < 0.08
    env.sim.step(10)
    assert _height_says(env) == [o.removeprefix("test/") for o in env.object_ids]
    env.close()


@pytest.mark.sim
def test_randomization_switches_change_what_they_should() -> None:
    off = _env("sapien", 3, randomization=RandomizationConfig(seed=5))
    off.reset_all()
    obs_off = off.observe()[0]
    assert np.array_equal(off.start_pose, off.rest_pose)
    assert all(o is off.pool.entries[k].asset for o, k in zip(off.objects, off.entry, strict=True))

    on = RandomizationConfig(seed=5, start_pose=True, mass=True, friction=True, obs_noise=True)
    env = _env("sapien", 3, randomization=on)
    env.reset_all()
    assert env.object_ids == off.object_ids  # the pool draws use their own stream
    shift = env.start_pose[:, :2] - env.rest_pose[:, :2]
    assert np.all(np.abs(shift) <= on.max_shift + 1e-12) and np.all(np.abs(shift) > 1e-5)
    yaw = np.degrees(np.abs(quat_to_rotvec(env.start_pose[:, 3:])[:, 2] - quat_to_rotvec(env.rest_pose[:, 3:])[:, 2]))
    assert np.all(yaw <= on.max_yaw + 1e-9) and np.all(yaw > 1e-3)
    assert np.allclose(env.sim.object_pose()[:, :2], env.start_pose[:, :2], atol=2e-4)  # really put there
    for obj, k in zip(env.objects, env.entry, strict=True):
        base = env.pool.entries[k].asset
        assert 0.8 <= obj.density / base.density <= 1.2 and obj.density != base.density
        assert 0.8 <= obj.friction / base.friction <= 1.2 and obj.friction != base.friction
    # noise only on the noisy blocks: compare with the same env's noise-free layout of its own state
    obs, _ = env.observe()
    layout = env.obs_layout
    clean = _env("sapien", 3, randomization=on.model_copy(update={"obs_noise": False}))
    clean.reset_all()
    obs_clean = clean.observe()[0]
    dq = (layout.unpack(obs, "q") - layout.unpack(obs_clean, "q")).flatten()
    assert 0.003 < float(dq.std()) < 0.007  # configured 0.005 rad over 48 values
    assert torch.equal(layout.unpack(obs, "goal_q"), layout.unpack(obs_clean, "goal_q"))
    assert not torch.equal(obs_off, obs)
    for e in (off, env, clean):
        e.close()


@pytest.mark.sim
def test_one_object_env_randomizes_mass_and_start_pose_and_master_switch_turns_it_off() -> None:
    from helpers_env import build_grasp_env

    rand = RandomizationConfig(seed=1, start_pose=True, mass=True)
    env = build_grasp_env("pybullet", 2, reach_steps=2, settle_steps=1, randomization=rand)
    env.reset_all()
    assert all(o is not env.obj and o.object_id == env.obj.object_id for o in env.objects)
    assert not np.array_equal(env.start_pose, env.rest_pose)
    env.close()
    env = build_grasp_env("pybullet", 2, reach_steps=2, settle_steps=1,
                          randomization=rand.model_copy(update={"enabled": False}))  # fmt: skip
    env.reset_all()
    assert all(o is env.obj for o in env.objects) and np.array_equal(env.start_pose, env.rest_pose)
    env.close()


def test_bad_pools_and_settings_are_clear_errors() -> None:
    reg = load_registry()
    hand = reg.build_hand("allegro")
    e = _entry(hand, "short")
    with pytest.raises(AssetError, match="no entries"):
        GraspPool([])
    pool = GraspPool([e])
    for bad, msg in (([-1.0], "finite, >= 0"), ([0.0], "not all 0"), ({"nope": 1.0}, "no entry for object"),
                     ([1.0, 1.0], "one per entry")):  # fmt: skip
        with pytest.raises(ConfigError, match=msg):
            pool.set_weights(bad)
    sim = reg.build_sim("sapien", SceneConfig(num_envs=1))
    with pytest.raises(ConfigError, match="either an object and its grasps"):
        GraspEnv(sim, hand, e.asset, None, EnvConfig(), pool=pool)
    with pytest.raises(ConfigError, match="not blocks of the observation"):
        GraspEnv.from_pool(sim, hand, pool, EnvConfig(randomization=RandomizationConfig(noise_std={"goal_x": 0.1})))
    sim.close()
