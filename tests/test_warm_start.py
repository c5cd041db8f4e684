"""Behaviour-cloning warm start (``TrainConfig.warm_start``): real scripted rollouts in SAPIEN on the test dataset's
two training objects, the imitation loss going down, exact repeats with a seed, critic-only iterations, the frozen
actor normalizer, and the pieces on their own."""

from __future__ import annotations

import json

import pytest
import torch
from test_train_expert import DATASET, FAST, _train, clusters  # noqa: F401 (clusters: the module's fixture)

from ges_core.training.checkpoint import read_checkpoint
from ges_core.training.warm_start import STD_FLOOR, fit_normalizer, sync_wrist_mirror

pytestmark = pytest.mark.sim
WARM = [
    "warm_start.enabled=true", "warm_start.samples=48", "warm_start.epochs=30", "warm_start.batch_size=16",
    "warm_start.critic_iterations=1", "warm_start.all_objects=true", "checkpoint_interval=1",
]  # fmt: skip
"""48 demonstration samples (24 control steps x 2 envs) of the scripted expert on both objects, 30 epochs."""


def _record(out) -> dict:
    return json.loads((out / "warm_start.json").read_text())


def test_cloning_lowers_the_imitation_loss_and_repeats_exactly(tmp_path, clusters) -> None:  # noqa: F811
    runs = {name: _train(tmp_path / name, clusters, "iterations=1", f"seed={seed}", *WARM)
            for name, seed in (("a", 5), ("b", 5), ("c", 6))}  # fmt: skip
    rec = _record(tmp_path / "a")
    loss = rec["imitation_loss"]
    assert len(loss) == 30 + 1 and loss[-1] < 0.5 * loss[0]  # measured 0.28 -> 0.004 at seed 5
    assert rec["demo_env_steps"] == 48 and set(rec["objects"]) == {"procedural/box/000", "procedural/sphere/000"}
    assert runs["a"].env_steps == 48 + 2 * 4  # the demonstrations count, then one iteration of 2 envs x 4 steps
    assert runs["a"].warm_start["imitation_loss"] == loss
    a, b, c = (read_checkpoint(r.checkpoint) for r in runs.values())
    assert all(torch.equal(a["actor_state_dict"][k], b["actor_state_dict"][k]) for k in a["actor_state_dict"])
    assert any(not torch.equal(a["actor_state_dict"][k], c["actor_state_dict"][k]) for k in a["actor_state_dict"])
    std = a["actor_state_dict"]["distribution.std_param"]
    assert torch.allclose(std, torch.full_like(std, 0.02))  # warm_start.init_std, untouched by a critic iteration


def test_critic_iterations_leave_the_actor_and_its_frozen_normalizer(tmp_path, clusters) -> None:  # noqa: F811
    out = tmp_path / "run"
    _train(out, clusters, "iterations=3", *WARM, "warm_start.critic_iterations=2")
    ck = [read_checkpoint(out / "checkpoints" / f"model_{i}.pt") for i in (1, 2, 3)]
    actor = [c["actor_state_dict"] for c in ck]
    critic = [c["critic_state_dict"] for c in ck]
    weights = [k for k in actor[0] if k.startswith("mlp.")]
    assert all(torch.equal(actor[0][k], actor[1][k]) for k in weights)  # iterations 1-2: critic only
    assert any(not torch.equal(critic[0][k], critic[1][k]) for k in critic[0] if k.startswith("mlp."))
    assert any(not torch.equal(actor[1][k], actor[2][k]) for k in weights)  # iteration 3: PPO moves the actor
    assert torch.equal(actor[0]["obs_normalizer._mean"], actor[2]["obs_normalizer._mean"])  # frozen at the fit
    assert not torch.equal(critic[0]["obs_normalizer._mean"], critic[2]["obs_normalizer._mean"])  # still updating
    rows = [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]
    assert [r["update"] for r in rows] == ["critic", "critic", "ppo"]


def test_residual_mode_skips_the_warm_start(tmp_path, clusters) -> None:  # noqa: F811
    run = _train(tmp_path / "run", clusters, "iterations=1", "action_mode=residual", *WARM)
    assert run.warm_start is None and not (tmp_path / "run" / "warm_start.json").exists()
    assert run.env_steps == 2 * 4 + 2  # the usual normalizer warm-up step, no demonstrations


def test_fit_normalizer_sets_mean_and_floored_std() -> None:
    from rsl_rl.modules import EmpiricalNormalization

    class Model(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.obs_normalizer = EmpiricalNormalization(2)

    gen = torch.Generator().manual_seed(0)
    obs = torch.stack([3.0 + 2.0 * torch.randn(500, generator=gen), torch.full((500,), 7.0)], dim=1)
    model = Model().train()
    fit_normalizer(model, obs, freeze=True)
    norm = model.obs_normalizer
    assert torch.allclose(norm._mean[0], obs.mean(0)) and abs(float(norm._std[0, 0]) - float(obs[:, 0].std())) < 0.01
    assert float(norm._std[0, 1]) == pytest.approx(STD_FLOOR)  # a constant feature keeps the floor, not 0
    before = norm._mean.clone()
    norm.update(obs + 100.0)  # frozen: an update changes nothing
    assert torch.equal(norm._mean, before)


def test_sync_wrist_mirror_copies_the_env_target() -> None:
    from helpers_env import build_grasp_env

    from ges_core.policy import ExpertContext
    from ges_core.registry import load_registry

    reg = load_registry()
    env = build_grasp_env("sapien", 2, reach_steps=2, settle_steps=1)
    try:
        env.reset_all()
        expert = reg.build_expert("scripted", ExpertContext.of_env(env, registry=reg))
        sync_wrist_mirror(expert, env)  # before its first action the expert has no mirror: nothing happens
        action = expert.act(env.observe()[0])
        env.apply_action(action + 0.3)  # the env's target moves off the expert's copy
        assert not torch.allclose(expert.plan["target_pos"], torch.as_tensor(env.wrist_target[:, :3]))
        sync_wrist_mirror(expert, env)
        assert torch.equal(expert.plan["target_pos"], torch.as_tensor(env.wrist_target[:, :3]))
        assert torch.equal(expert.plan["target_rot"], torch.as_tensor(env.wrist_target[:, 3:]))
    finally:
        env.close()


def test_anchor_steps_pull_the_actor_back_toward_the_demonstrations(tmp_path, clusters) -> None:  # noqa: F811
    from ges_core.training.warm_start import imitation_loss

    runs = {}
    for name, steps in (("free", 0), ("anchored", 40)):
        out = tmp_path / name
        _train(out, clusters, "iterations=3", *WARM, "ppo.learning_rate=3e-3", "ppo.schedule=fixed",
               f"warm_start.anchor_steps={steps}", "warm_start.anchor_learning_rate=1e-3")  # fmt: skip
        runs[name] = read_checkpoint(out / "checkpoints" / "last.pt")
    # the same seed: both cloned the same demonstrations; measure each final actor on fresh scripted ones
    from ges_core.registry import load_registry
    from ges_core.training.config import load_train_config
    from ges_core.training.envs import build_setup
    from ges_core.training.run import rsl_config
    from ges_core.training.runner import GraspRunner
    from ges_core.training.warm_start import collect_demonstrations

    cfg = load_train_config("tiny", overrides=[*FAST, *WARM])
    torch.manual_seed(cfg.seed)
    setup = build_setup(DATASET, cfg, load_registry(), clusters)
    try:
        runner = GraspRunner(setup.venv, rsl_config(cfg, False), tmp_path / "probe", curriculum=setup.curriculum,
                             meta={}, settings=cfg)  # fmt: skip
        expert = load_registry().build_expert("scripted", _context(setup), **cfg.warm_start.expert_settings)
        demo = collect_demonstrations(setup.venv, expert, 48, 0.0, torch.Generator().manual_seed(0))
        losses = {}
        for name, data in runs.items():
            runner.alg.actor.load_state_dict(data["actor_state_dict"])
            losses[name] = imitation_loss(runner.alg.actor, demo.obs, demo.actions)
    finally:
        setup.venv.close()
    assert losses["anchored"] < losses["free"]
    # a resumed anchored run reads its demonstrations back from the run folder
    resumed = _train(tmp_path / "anchored", clusters, "iterations=4", *WARM, "warm_start.anchor_steps=40",
                     resume=True)  # fmt: skip
    assert resumed.iterations == 4 and (tmp_path / "anchored" / "demonstrations.pt").is_file()
    assert not (tmp_path / "free" / "demonstrations.pt").exists()


def _context(setup):
    from ges_core.policy import ExpertContext

    return ExpertContext.of_env(setup.env, sim=setup.sim)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_nogoal_teacher_labels_what_the_goal_env_labels(clusters, workers) -> None:  # noqa: F811
    """NoGoal (``env.goal_prior=false``): the demonstrator reads the policy's observation with the env's exact goal
    put in. Cross-check against a Goal env built alike (the same states, randomization off): the teacher's view
    equals the Goal env's own observation bit for bit, the labels are the same, and the student keeps its own view
    (the Goal observation without the goal blocks). With 2 env workers (both envs) the goal comes from them."""
    from ges_core.env.layout import GOAL_BLOCKS
    from ges_core.registry import load_registry
    from ges_core.training.config import load_train_config
    from ges_core.training.envs import build_setup
    from ges_core.training.run import _demonstrator
    from ges_core.training.warm_start import collect_demonstrations

    reg, demos, firsts = load_registry(), {}, {}
    for goal in (True, False):
        cfg = load_train_config("tiny", overrides=[*FAST, *WARM, f"env.goal_prior={str(goal).lower()}",
                                                   "env.randomization.enabled=false",
                                                   f"workers={workers}"])  # fmt: skip
        torch.manual_seed(cfg.seed)
        setup = build_setup(DATASET, cfg, reg, clusters)
        try:
            layout = setup.env.obs_layout
            assert layout.goal is goal
            obs = setup.venv.get_observations()["policy"]
            firsts[goal] = obs if goal else layout.add_goal(obs, torch.as_tensor(setup.env.goal_obs))
            expert = _demonstrator(setup, cfg, reg)  # the run's own: built for the observation with the goal
            assert expert.obs_layout == layout.with_goal()
            demos[goal] = collect_demonstrations(setup.venv, expert, 48, 0.0, torch.Generator().manual_seed(0))
        finally:
            setup.venv.close()
    assert torch.equal(firsts[True], firsts[False])
    full = demos[True]
    assert torch.equal(demos[False].actions, full.actions)
    goal_cols = torch.cat([torch.arange(full.obs.shape[1])[layout.with_goal().slices[g]] for g in GOAL_BLOCKS])
    keep = torch.ones(full.obs.shape[1], dtype=torch.bool)
    keep[goal_cols] = False
    assert torch.equal(demos[False].obs, full.obs[:, keep])


def test_a_nogoal_run_warm_starts_from_its_teacher(tmp_path, clusters) -> None:  # noqa: F811
    """The warm start runs where the policy has no goal blocks: the cloning learns, the checkpoint is a NoGoal one."""
    out = tmp_path / "nogoal"
    summary = _train(out, clusters, "iterations=1", "seed=5", "env.goal_prior=false", *WARM)
    loss = _record(out)["imitation_loss"]
    assert loss[-1] < 0.5 * loss[0]
    made_for = dict(read_checkpoint(summary.checkpoint)["ges"]["made_for"]["observation"])
    assert "goal_q" not in made_for and "q" in made_for
