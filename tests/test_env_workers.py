"""Env workers (ges_core.env.workers): the same trajectories as one process, clear faults, no orphans, PPO on top.

Real SAPIEN envs on the test dataset's grasps throughout; a worker process costs a few seconds to start (imports).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from functools import partial

import numpy as np
import pytest
import torch
from helpers_tasks import gone_within, process_gone

from ges_core.env.success import EndReason
from ges_core.env.workers import SubprocVecEnv, split_envs
from ges_core.errors import ConfigError, SimulationError
from ges_core.registry import load_registry
from ges_core.training.config import load_train_config
from ges_core.training.envs import build_setup, env_config, worker_env

pytestmark = pytest.mark.sim
DATASET = os.path.join(os.path.dirname(__file__), "data", "dataset_v2")
FAST = ["env.reach_steps=4", "env.settle_steps=1", "env.episode_length=10", "curriculum.enabled=false",
        "hand=allegro", "sim=sapien"]  # fmt: skip
"""Short episodes (10 control steps) so 30 steps see several auto-resets; the tiny preset's randomization (start
pose, mass, friction, observation noise) stays on."""
METRIC_RTOL = 1e-12
"""The Table 3 oscillation sums go through a (n, 6 + K) @ (6 + K, 2) BLAS product whose rounding depends on the
batch's row count, so workers (fewer rows each) agree with one process to the last bits only; everything else is
compared bit for bit."""


def _setup(workers: int, num_envs: int = 4, *extra: str):
    cfg = load_train_config("tiny", overrides=[*FAST, f"num_envs={num_envs}", f"workers={workers}", *extra])
    return build_setup(DATASET, cfg, load_registry())


def _rollout(venv, steps: int = 30) -> list:
    """Seeded random actions; a NaN row in env 1 at step 5; the pool narrowed to one object at step 12."""
    gen = torch.Generator().manual_seed(1)
    out = [venv.get_observations()["policy"].clone()]
    for t in range(steps):
        actions = torch.rand(venv.num_envs, venv.num_actions, generator=gen) * 2 - 1
        if t == 5:
            actions[1, 3] = float("nan")
        if t == 12:
            venv.env.pool.set_weights({venv.env.pool.keys[0]: 1.0})
        out.append(venv.step(actions))
    return out


def _same(a, b, key: str) -> None:
    if key.startswith("/metrics/") or key.startswith("episode_metrics"):
        assert torch.allclose(a, b, rtol=METRIC_RTOL, atol=0, equal_nan=True), (key, a, b)
    else:
        assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a.nan_to_num(7.0), b.nan_to_num(7.0)), key


def test_two_workers_step_exactly_like_one_process_and_close_cleanly() -> None:
    one, two = _setup(1).venv, _setup(2).venv
    assert isinstance(two, SubprocVecEnv) and two.slices == [(0, 1), (2, 3)]
    a, b = _rollout(one), _rollout(two)
    _same(a[0], b[0], "first observation")
    ended, unstable = 0, 0
    for t, ((oa, ra, da, xa), (ob, rb, db, xb)) in enumerate(zip(a[1:], b[1:], strict=True)):
        _same(oa["policy"], ob["policy"], f"obs {t}")
        _same(ra, rb, f"reward {t}")
        _same(da, db, f"done {t}")
        assert xa.keys() == xb.keys() and xa["log"].keys() == xb["log"].keys(), t
        for key in xa["log"]:
            _same(xa["log"][key], xb["log"][key], key)
        for key in set(xa) - {"log", "episode_metrics"}:
            _same(xa[key], xb[key], key)
        for key in xa.get("episode_metrics", {}):
            _same(xa["episode_metrics"][key], xb["episode_metrics"][key], f"episode_metrics/{key}")
        ended += int(da.sum())
        unstable += int((xa["end_reason"] == int(EndReason.UNSTABLE)).sum())
    # not a trivial trajectory: episodes ended (and restarted from the pool), the NaN row ended one unstable,
    # the observations moved, the narrowed pool reached the workers
    assert ended >= 8 and unstable >= 1 and two.fault_counts == one.fault_counts == {"nan_actions": 1}
    assert not torch.equal(a[1][0]["policy"], a[-1][0]["policy"])
    assert set(b[-1][3]["entry"].tolist()) == {0}
    assert torch.equal(one.episode_length_buf, two.episode_length_buf)
    assert one.env.random.state() == two.env.random.state()  # per env, env order: checkpoints move across counts
    # other GraspEnv state reads through from the workers, joined in env order
    assert np.array_equal(one.env.wrist_target, two.env.wrist_target) and one.env.object_ids == two.env.object_ids
    with pytest.raises(AttributeError, match="no_such_thing"):
        two.env.no_such_thing  # noqa: B018
    procs = list(two._procs)
    two.close()
    two.close()
    assert all(p.exitcode == 0 for p in procs)
    with pytest.raises(SimulationError, match="closed"):
        two.step(torch.zeros(4, two.num_actions))
    one.close()


def _make(num_envs: int):
    cfg = load_train_config("tiny", overrides=[*FAST, f"num_envs={num_envs}"])
    setup = build_setup(DATASET, cfg, load_registry())
    setup.venv.close()
    registry = load_registry()
    make = partial(worker_env, registry.rebuild, "allegro", "sapien", setup.pool, env_config(cfg), scene=setup.scene)
    return make, setup


def test_a_dead_or_hung_worker_is_a_clear_error_never_a_hang() -> None:
    make, setup = _make(2)
    venv = SubprocVecEnv(make, 2, 1, hand=setup.env.hand, pool=setup.pool, timeout=3.0)
    venv.step(torch.zeros(2, venv.num_actions))
    os.kill(venv._procs[0].pid, signal.SIGSTOP)  # hung: alive, silent
    t0 = time.monotonic()
    with pytest.raises(SimulationError, match=r"env worker 0 \(pid \d+, envs 0-1 of 2\) gave no answer in 3 s"):
        venv.step(torch.zeros(2, venv.num_actions))
    assert time.monotonic() - t0 < 10 and not venv._procs[0].is_alive()  # the stopped worker was killed
    with pytest.raises(SimulationError, match="closed"):
        venv.step(torch.zeros(2, venv.num_actions))

    venv = SubprocVecEnv(make, 2, 2, hand=setup.env.hand, pool=setup.pool)
    os.kill(venv._procs[1].pid, signal.SIGKILL)
    with pytest.raises(SimulationError, match=r"env worker 1 \(pid \d+, envs 1-1 of 2\) died \(killed by SIGKILL\)"):
        venv.step(torch.zeros(2, venv.num_actions))
    assert not venv._procs[0].is_alive()
    venv.close()


def _raise_runtime(env_ids):
    raise RuntimeError(f"boom in envs {env_ids}")


def _raise_config(env_ids):
    raise ConfigError("sapien: contact_offset=5 m; give a value in (0, 0.1] or leave it unset")


def test_worker_exceptions_reach_the_main_process() -> None:
    hand = load_registry().build_hand("allegro")
    with pytest.raises(SimulationError, match=r"(?s)env worker \d .*raised an exception.*RuntimeError: boom in envs"):
        SubprocVecEnv(_raise_runtime, 2, 1, hand=hand)
    with pytest.raises(ConfigError, match="contact_offset=5 m"):  # our own errors come through as they are
        SubprocVecEnv(_raise_config, 2, 1, hand=hand)
    with pytest.raises(ConfigError, match="make_env must be picklable"):
        SubprocVecEnv(lambda env_ids: None, 2, 1, hand=hand)
    with pytest.raises(ConfigError, match="3 worker"):
        split_envs(2, 3)


PARENT = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from test_env_workers import _make
    from ges_core.env.workers import SubprocVecEnv

    if __name__ == "__main__":
        make, setup = _make(2)
        venv = SubprocVecEnv(make, 2, 2, hand=setup.env.hand, pool=setup.pool)
        print(" ".join(str(p.pid) for p in venv._procs), flush=True)
        time.sleep(600)
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_exit_when_the_parent_is_killed(tmp_path) -> None:
    script = tmp_path / "parent.py"
    script.write_text(PARENT.format(tests=os.path.dirname(__file__)))
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2 and not any(process_gone(p) for p in pids)
    finally:
        parent.kill()
        parent.wait()
    assert gone_within(pids, 10), pids


def test_ppo_with_two_workers_learns_exactly_what_one_process_learns(tmp_path) -> None:
    from ges_core.cli import main
    from ges_core.training.checkpoint import read_checkpoint
    from ges_core.training.run import train_expert

    fast = [*FAST, "num_envs=2", "ppo.num_steps_per_env=12", "ppo.normalizer_warmup=1", "ppo.num_mini_batches=2",
            "ppo.actor_hidden=[32, 32]", "ppo.critic_hidden=[32, 32]", "iterations=1"]  # fmt: skip
    s1 = train_expert(DATASET, load_train_config("tiny", overrides=fast), tmp_path / "w1", registry=load_registry(),
                      progress=False)  # fmt: skip
    overrides = [x for item in fast for x in ("-o", item)]
    code = main(["train-expert", DATASET, "--workers", "2", "--out", str(tmp_path / "w2"), "--no-progress", *overrides])
    summary = json.loads((tmp_path / "w2" / "summary.json").read_text())
    assert code == 0 and summary["iterations"] == 1 and summary["env_steps"] == s1.env_steps == 2 * 12 + 2
    assert summary["episodes"] == s1.episodes >= 1
    c1, c2 = (read_checkpoint(tmp_path / w / "checkpoints" / "last.pt") for w in ("w1", "w2"))
    assert c2["ges"]["train_config"]["workers"] == 2
    for key, value in c1["actor_state_dict"].items():
        assert torch.equal(value, c2["actor_state_dict"][key]), key
    assert c1["ges"]["state"]["env_rng"] == c2["ges"]["state"]["env_rng"] and len(c2["ges"]["state"]["env_rng"]) == 2


def test_residual_mode_runs_on_workers() -> None:
    setup = _setup(2, 2, "action_mode=residual")
    td = setup.venv.get_observations()
    assert td["base_action"].shape == (2, setup.venv.num_actions) and np.isfinite(td["base_action"].numpy()).all()
    td, reward, done, _ = setup.venv.step(torch.zeros(2, setup.venv.num_actions))
    assert torch.isfinite(reward).all() and td["base_action"].abs().sum() > 0
    setup.venv.close()


def test_each_env_draws_from_its_own_streams_whatever_the_split() -> None:
    """One randomizer over envs 0-3 against two over 0-1 and 2-3 (as two workers hold them): the same start poses,
    physics scales and noise per env, also when only some envs restart; states round-trip; bad states are errors."""
    from ges_core.env.randomization import RandomizationConfig, Randomizer
    from ges_core.objects.simple import box_asset

    cfg = RandomizationConfig(seed=4, start_pose=True, mass=True, friction=True, obs_noise=True)
    slices = {"q": slice(0, 3), "dq": slice(3, 6), "tip_pos": slice(6, 9), "wrist_pose": slice(9, 12),
              "obj_pos": slice(12, 15)}  # fmt: skip
    whole, halves = Randomizer(cfg, slices, range(4)), [Randomizer(cfg, slices, ids) for ids in ((0, 1), (2, 3))]
    rest = np.tile([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0], (4, 1))
    box = box_asset((0.02, 0.02, 0.02), object_id="test/box")
    for rows in ([0, 1, 2, 3], [1, 3], [3]):  # restarts of some envs only: the others' streams must not move
        poses = whole.start_poses(rest[rows], rows)
        split = [h.start_poses(rest[[r % 2]], [r % 2]) for r in rows for h in [halves[r // 2]]]
        assert np.array_equal(poses, np.concatenate(split)) and not np.allclose(poses, rest[rows])
        assert [whole.physics(box, r).density for r in rows] == [halves[r // 2].physics(box, r % 2).density
                                                                 for r in rows]  # fmt: skip
    obs = np.zeros((4, 15), dtype=np.float32)
    parts = [np.zeros((2, 15), dtype=np.float32) for _ in halves]
    whole.add_noise(obs, [1, 2])
    halves[0].add_noise(parts[0], [1])
    halves[1].add_noise(parts[1], [0])
    assert np.array_equal(obs, np.concatenate(parts)) and not obs[[0, 3]].any() and obs[[1, 2]].all()
    assert whole.state() == halves[0].state() + halves[1].state()
    again = Randomizer(cfg.model_copy(update={"seed": 5}), slices, range(4))
    again.set_state(whole.state())
    assert again.state() == whole.state()
    with pytest.raises(ConfigError, match="2 entries, this environment has 4 envs"):
        again.set_state(whole.state()[:2])
    with pytest.warns(UserWarning, match="restart from the seed"):  # a checkpoint from before per-env streams
        again.set_state([{}, {}, {}, {}])


def test_training_on_grasps_made_for_another_description_of_the_hand_is_warned_about(tmp_path, monkeypatch):
    """``ges train-expert`` (build_setup) compares the hand it builds with the one the dataset's manifest describes,
    as evaluation does (tests/test_env_evaluate.py), after building it prepared (``built_prepared``, as ges synth
    does). The test dataset predates hand descriptions: it is given one with other gains."""
    import shutil

    from ges_core.training import envs

    built = []
    real = envs.built_prepared
    monkeypatch.setattr(envs, "built_prepared", lambda registry, name: built.append(name) or real(registry, name))

    from ges_core.dataset.hands import HandChangedWarning, hand_entry

    copy = tmp_path / "ds"
    shutil.copytree(DATASET, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    entry = hand_entry(load_registry().build_hand("allegro"))
    joint = next(k for k in entry["description"] if k.startswith("pd_stiffness["))
    entry["description"][joint], entry["hash"] = 123.0, "0" * 16
    manifest["hands"] = {"allegro": entry}
    (copy / "manifest.json").write_text(json.dumps(manifest))
    cfg = load_train_config("tiny", overrides=[*FAST, "num_envs=2", "workers=1"])
    with pytest.warns(HandChangedWarning, match=rf"{joint.replace('[', '.').replace(']', '.')}: 123.0 -> 400.0"):
        build_setup(copy, cfg, load_registry()).venv.close()
    assert built == ["allegro"]


def test_training_envs_run_in_the_datasets_stage1_physics_unless_the_run_gives_its_own(tmp_path) -> None:
    """``build_setup`` builds its envs, the workers' and the in-run evaluation's in the scene the dataset's Stage 1
    ran in (what ``ges eval-experts`` scores in), not in ``SceneConfig``'s defaults; ``-o scene.KEY=VALUE`` gives a
    run its own. Read back from PhysX itself (solver iterations, hand friction) as well as from the config."""
    import shutil

    from ges_core.training.evaluation import InRunEvaluator

    copy = tmp_path / "ds"
    shutil.copytree(DATASET, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["run_config"]["scene"] |= {"solver_iterations": 17, "hand_friction": 0.7}
    (copy / "manifest.json").write_text(json.dumps(manifest))

    def physx(sim) -> tuple[int, set[float]]:
        hand = sim._envs[0].hand
        shapes = [s for link in hand.get_links() for s in link.collision_shapes]
        return hand.get_solver_position_iterations(), {round(s.physical_material.static_friction, 6) for s in shapes}

    for extra, iterations, friction in (((), 17, 0.7), (("scene.solver_iterations=9",), 9, 1.0)):
        cfg = load_train_config("tiny", overrides=[*FAST, "num_envs=2", "workers=1", *extra])
        setup = build_setup(copy, cfg, load_registry())
        try:
            sim = setup.venv.env.sim
            assert (sim.config.num_envs, sim.config.solver_iterations, sim.config.hand_friction) == (
                2,
                iterations,
                friction,
            )
            assert physx(sim) == (iterations, {friction})
            worker = worker_env(load_registry, "allegro", "sapien", setup.pool, env_config(cfg), [1], scene=setup.scene)
            assert worker.sim.config.num_envs == 1 and physx(worker.sim) == (iterations, {friction})
            worker.sim.close()
            evaluator = InRunEvaluator.for_run(cfg, setup, load_registry())
            assert (evaluator.scene.solver_iterations, evaluator.scene.hand_friction) == (iterations, friction)
        finally:
            setup.venv.close()
