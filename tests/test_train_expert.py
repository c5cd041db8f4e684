"""``ges train-expert``: a real (tiny) PPO run on the test dataset's grasps in SAPIEN: checkpoints, resume, seeded
repeat, the checkpoint as an Expert, NaN actions, residual mode, a kill while writing a checkpoint."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest
import torch

from ges_core.cli import main
from ges_core.clustering import ClusterMember, Clusters, save_clusters
from ges_core.errors import ConfigError
from ges_core.policy import ExpertContext
from ges_core.registry import load_registry
from ges_core.training.checkpoint import latest_loadable, read_checkpoint, write_checkpoint
from ges_core.training.config import PRESETS, load_train_config
from ges_core.training.run import train_expert

pytestmark = pytest.mark.sim
DATASET = os.path.join(os.path.dirname(__file__), "data", "dataset_v2")
FAST = [
    "num_envs=2", "ppo.num_steps_per_env=4", "ppo.normalizer_warmup=1", "ppo.actor_hidden=[32, 32]",
    "ppo.critic_hidden=[32, 32]", "ppo.num_mini_batches=2", "env.reach_steps=4", "env.settle_steps=1",
    "curriculum.max_iterations=1", "checkpoint_interval=1", "hand=allegro", "sim=sapien",
]  # fmt: skip
"""A PPO run of a few seconds: 2 envs x 4 steps per iteration, small networks, a short reach."""


@pytest.fixture(scope="module")
def clusters(tmp_path_factory) -> Clusters:
    """Both training objects of the test dataset in cluster 0 (the box nearer its centre), hand-written."""
    members = {
        oid: ClusterMember(
            object_id=oid,
            category=oid.split("/")[1],
            split="train",
            cluster=0,
            assigned_by="category",
            features=np.array([d]),
            distance=d,
            nearest_cluster=0,
        )  # fmt: skip
        for oid, d in (("procedural/box/000", 0.1), ("procedural/sphere/000", 0.5))
    }
    c = Clusters(k=2, seed=0, feature_names=("f",), mean=np.zeros(1), std=np.ones(1), centres=np.zeros((2, 1)),
                 kmeans_centres=np.zeros((2, 1)), objects=members, categories={"box": 0, "sphere": 0})  # fmt: skip
    save_clusters(c, tmp_path_factory.mktemp("clusters") / "clusters.json")
    return c


def _train(out, clusters, *extra, resume=False, **kw):
    cfg = load_train_config("tiny", overrides=[*FAST, *extra])
    return train_expert(DATASET, cfg, out, registry=load_registry(), clusters=clusters, resume=resume, progress=False,
                        **kw)  # fmt: skip


def _weights(path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path)["actor_state_dict"]


def test_run_checkpoint_resume_and_curriculum(tmp_path, clusters) -> None:
    out = tmp_path / "run"
    first = _train(out, clusters, "iterations=2")
    assert first.iterations == 2 and first.env_steps == 2 * 4 * 2 + 2 * 1  # + the normalizer warm-up step
    assert [json.loads(line)["iteration"] for line in (out / "history.jsonl").read_text().splitlines()] == [1, 2]
    # stage 1 holds the box (ceil(0.3 x 2) = 1 object), the cap of 1 iteration promoted to 2, then to 3
    assert [p.split(":")[0] for p in first.promotions] == ["iteration 1", "iteration 2"]
    assert (out / "curriculum.log").read_text().count("curriculum stage") == 2
    ckpt = read_checkpoint(out / "checkpoints" / "last.pt")
    assert ckpt["iter"] == 2 and ckpt["ges"]["state"]["curriculum"]["index"] == 2
    assert ckpt["ges"]["made_for"]["hand"] == "allegro" and ckpt["ges"]["objects"] == sorted(ckpt["ges"]["objects"])
    before = _weights(out / "checkpoints" / "model_2.pt")
    with pytest.raises(ConfigError, match="pass --resume"):
        _train(out, clusters, "iterations=3")
    again = _train(out, clusters, "iterations=3", "evaluation.interval=1", "evaluation.episodes=1", resume=True)
    assert again.iterations == 3 and again.resumed_from.endswith("last.pt") and again.stage == 3
    # the resume keeps the stored config but takes evaluations given on its command line (they touch no weight)
    assert [json.loads(x)["iteration"] for x in (out / "evaluations.jsonl").read_text().splitlines()] == [3]
    assert read_checkpoint(out / "checkpoints" / "last.pt")["iter"] == 3
    assert [json.loads(x)["iteration"] for x in (out / "history.jsonl").read_text().splitlines()] == [1, 2, 3]
    after = _weights(out / "checkpoints" / "model_3.pt")
    assert any(not torch.equal(before[k], after[k]) for k in before)  # the resumed iteration learned
    assert {p.name for p in (out / "logs").iterdir() if p.name.startswith("events")}  # TensorBoard files


@pytest.mark.parametrize("mode", ["absolute", "residual"])
def test_a_run_from_before_the_wrist_matrix_resumes_and_acts_in_todays_env(tmp_path, clusters, mode) -> None:
    """A checkpoint written before ``env.wrist_rotation`` existed (its stored config lacks the key; its policy reads
    the wrist as a rotation vector, ``wrist_pose`` 6 floats) resumes as it ran, not at today's default; in today's
    default environment (the matrix form) it acts on the recast observations exactly as in a rotation-vector one,
    the residual policy's base expert included."""
    from helpers_env import build_grasp_env

    from ges_core.experts.wrist_form import RecastWrist

    out = tmp_path / "old"
    _train(out, clusters, "iterations=1", "env.wrist_rotation=rotvec", f"action_mode={mode}")
    for path in (out / "checkpoints").glob("*.pt"):  # as the code before the setting wrote it
        data = torch.load(path, weights_only=False)
        del data["ges"]["train_config"]["env"]["wrist_rotation"]
        torch.save(data, path)
    last = out / "checkpoints" / "last.pt"
    assert dict(read_checkpoint(last)["ges"]["made_for"]["observation"])["wrist_pose"] == 6
    again = _train(out, clusters, "iterations=2", resume=True)
    assert again.iterations == 2 and again.resumed_from.endswith("last.pt")
    assert dict(read_checkpoint(last)["ges"]["made_for"]["observation"])["wrist_pose"] == 6
    actions = {}
    for form in ("rotvec", "matrix"):
        env = build_grasp_env("sapien", 2, reach_steps=4, settle_steps=1, wrist_rotation=form)
        try:
            env.reset_all()
            obs, _ = env.observe()
            expert = load_registry().build_expert("ppo", ExpertContext.of_env(env, sim="sapien"), checkpoint=str(last))
            assert isinstance(expert, RecastWrist) == (form == "matrix") and obs.shape[1] == env.obs_layout.size
            actions[form] = expert.act(obs)
        finally:
            env.sim.close()
    torch.testing.assert_close(actions["matrix"], actions["rotvec"], atol=1e-5, rtol=0)


def test_seeded_runs_repeat_exactly(tmp_path, clusters) -> None:
    runs = [_train(tmp_path / name, clusters, "iterations=2", f"seed={seed}") for name, seed in
            (("a", 3), ("b", 3), ("c", 4))]  # fmt: skip
    a, b, c = (_weights(r.checkpoint) for r in runs)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert any(not torch.equal(a[k], c[k]) for k in a)


def test_checkpoint_is_an_expert_and_refuses_another_hand(tmp_path, clusters) -> None:
    from helpers_env import build_grasp_env

    run = _train(tmp_path / "run", clusters, "iterations=1")
    reg = load_registry()
    env = build_grasp_env("sapien", 2, reach_steps=2, settle_steps=1)
    env.reset_all()
    expert = reg.build_expert("ppo", ExpertContext.of_env(env, registry=reg), checkpoint=run.checkpoint)
    obs = env.observe()[0]
    act = expert.act(obs)
    assert act.shape == (2, 22) and torch.isfinite(act).all() and act.abs().max() <= 1.0
    assert torch.equal(act, expert.act(obs))  # deterministic: the Gaussian's mean
    env.close()
    shadow = reg.build_hand("shadow")
    sim = reg.build_sim("sapien")
    from helpers_env import grasp_targets

    from ges_core.env.grasp_env import EnvConfig, GraspEnv
    from ges_core.objects.simple import box_asset

    env = GraspEnv(sim, shadow, box_asset(), grasp_targets(shadow, 1), EnvConfig())
    with pytest.raises(ConfigError, match=r"made for hand 'allegro'.*this environment has hand 'shadow'"):
        reg.build_expert("ppo", ExpertContext.of_env(env), checkpoint=run.checkpoint)
    env.close()


def test_evaluation_takes_the_hand_from_the_checkpoint_and_refuses_another(tmp_path, clusters, capsys) -> None:
    """The test dataset holds both hands and registry.yaml's default hand is the Shadow: without --hand, `ges
    eval-experts` and `ges env baseline` run the Allegro the checkpoint was made for; --hand shadow is refused,
    naming both hands, before any result file is written."""
    run = _train(tmp_path / "run", clusters, "iterations=1")
    assert load_registry().default("hand") == "shadow"
    expert = f"ppo:checkpoint={run.checkpoint}"
    quick = ["--split", "train", "--select", "any", "-o", "env.episode_length=2", "-o", "env.reach_steps=2",
             "--no-progress"]  # fmt: skip
    out = tmp_path / "eval"
    assert main(["eval-experts", DATASET, "--expert", expert, "--episodes", "1", "--out", str(out), *quick]) == 0
    assert "| hand allegro |" in capsys.readouterr().out
    assert [p.name for p in out.iterdir()] == ["matrix-allegro-sapien.json"]
    refused = tmp_path / "refused"
    for command in (["eval-experts", "--episodes", "1"], ["env", "baseline", "--envs", "1"]):
        args = [*command[:-2], DATASET, "--hand", "shadow", "--expert", expert, *command[-2:], "--out", str(refused)]
        assert main([*args, *quick]) == 1
        err = capsys.readouterr().err
        assert re.search(r"--hand shadow: expert\(s\) made for another hand: 'ppo:checkpoint=.*' for 'allegro'", err)
    assert not refused.exists()


def test_nan_actions_end_episodes_and_training_goes_on(tmp_path, clusters, monkeypatch) -> None:
    """A policy output of NaN in one env: that episode ends unstable, the run counts it, and the rollout stores a
    finite action in its place, so the update stays finite and the run finishes."""
    from ges_core.training import runner as runner_mod

    original = runner_mod.GraspRunner._iteration
    injected = {"done": False}

    def nan_once(self, *args):
        act = self.alg.act

        def poisoned(obs):
            a = act(obs)
            if not injected["done"]:
                a[0] = float("nan")
                injected["done"] = True
            return a

        monkeypatch.setattr(self.alg, "act", poisoned)
        return original(self, *args)

    monkeypatch.setattr(runner_mod.GraspRunner, "_iteration", nan_once)
    run = _train(tmp_path / "run", clusters, "iterations=2", "curriculum.enabled=false")
    assert run.nan_actions == 1 and run.bad_updates == 0 and run.iterations == 2
    rows = [json.loads(x) for x in (tmp_path / "run" / "history.jsonl").read_text().splitlines()]
    assert rows[0]["nan_actions"] == 1 and rows[0]["reasons"].get("unstable", 0) >= 1
    assert all(torch.isfinite(w).all() for w in _weights(run.checkpoint).values())


def test_residual_mode_starts_at_its_base_expert_with_the_runs_base_settings(tmp_path, clusters) -> None:
    """A residual run on ``scripted:palm_shift=0.01`` stores the base settings; its checkpoint as an expert acts as
    that base at the start (not as the plain script, whose grasp is 1 cm elsewhere)."""
    from helpers_env import build_grasp_env

    run = _train(tmp_path / "run", clusters, "iterations=1", "action_mode=residual", "ppo.learning_rate=1e-9",
                 "ppo.schedule=fixed", "base_expert_settings={palm_shift: 0.01}")  # fmt: skip
    assert read_checkpoint(run.checkpoint)["ges"]["base_expert_settings"] == {"palm_shift": 0.01}
    reg = load_registry()
    env = build_grasp_env("sapien", 2, reach_steps=2, settle_steps=1)
    env.reset_all()
    ctx = ExpertContext.of_env(env, registry=reg)
    residual = reg.build_expert("ppo", ctx, checkpoint=run.checkpoint)
    deep, plain = reg.build_expert("scripted", ctx, palm_shift=0.01), reg.build_expert("scripted", ctx)
    obs = env.observe()[0]
    action = residual.act(obs)
    assert residual.residual and torch.allclose(action, deep.act(obs), atol=1e-4)
    assert (action - plain.act(obs)).abs().max() > 0.1  # the wrist heads for another grasp position
    env.close()


def test_a_hands_residual_scale_reaches_the_run_unless_the_run_sets_one(tmp_path, clusters) -> None:
    """The hand YAML's ``settings.train.residual_scale`` is what the run trains and stores (summary, the checkpoint
    the PPO expert reads its scale from); the run's own -o value wins over it."""
    hand_scale = ("settings.hand.allegro.settings={train: {residual_scale: 0.03}}",)
    common = ["iterations=1", "action_mode=residual"]
    for extra, scale in (([], 0.03), (["residual_scale=0.07"], 0.07)):
        cfg = load_train_config("tiny", overrides=[*FAST, *common, *extra])
        reg = load_registry(overrides=hand_scale)
        run = train_expert(DATASET, cfg, tmp_path / str(scale), registry=reg, clusters=clusters, progress=False)
        assert run.residual_scale == scale and f"residual x {scale:g}" in run.table()
        ckpt = read_checkpoint(run.checkpoint)
        assert ckpt["ges"]["residual_scale"] == scale and ckpt["ges"]["train_config"]["residual_scale"] == scale


def test_a_kill_while_writing_leaves_the_previous_checkpoint(tmp_path, monkeypatch) -> None:
    folder = tmp_path / "checkpoints"
    good = {"ges": {"format": "ges.ppo_expert", "version": 1}, "iter": 1}
    write_checkpoint(folder, good, 1, keep=3)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt  # the process stops in the middle of writing the new file

    monkeypatch.setattr(os, "fsync", killed)
    with pytest.raises(KeyboardInterrupt):
        write_checkpoint(folder, {**good, "iter": 2}, 2, keep=3)
    monkeypatch.undo()
    assert read_checkpoint(folder / "last.pt")["iter"] == 1 and not list(folder.glob(".*.tmp"))
    (folder / "last.pt").write_bytes(b"half a file")  # a file system without atomic renames
    path, data = latest_loadable(folder)
    assert path.name == "model_1.pt" and data["iter"] == 1


def test_presets_load_and_cli_errors(tmp_path, capsys) -> None:
    for name in PRESETS:
        assert load_train_config(name).preset == name
    # the shipped residual recipe (configs/residual_expert.yaml) still names only TrainConfig keys
    recipe = load_train_config("tiny", os.path.join(os.path.dirname(__file__), "..", "configs", "residual_expert.yaml"))
    assert (recipe.action_mode, recipe.ppo.schedule) == ("residual", "fixed") and recipe.ppo.critic_fit_epochs > 0
    with pytest.raises(ConfigError, match="unknown training preset 'huge'"):
        load_train_config("huge")
    code = main(["train-expert", DATASET, "--out", str(tmp_path / "x"), "--no-progress", "--clusters",
                 str(tmp_path / "none.json")])  # fmt: skip
    assert code == 1 and "run 'ges cluster DATASET' first" in capsys.readouterr().err


def test_an_update_that_diverges_is_undone(tmp_path, clusters, monkeypatch) -> None:
    """An update leaving a NaN weight: the weights from before it come back, the run counts it and goes on."""
    from rsl_rl.algorithms import PPO

    original = PPO.update
    calls = {"n": 0}

    def diverging(self):
        loss = original(self)
        calls["n"] += 1
        if calls["n"] == 1:
            with torch.no_grad():
                next(self.actor.parameters()).fill_(float("nan"))
        return loss

    monkeypatch.setattr(PPO, "update", diverging)
    run = _train(tmp_path / "run", clusters, "iterations=2", "curriculum.enabled=false")
    assert run.bad_updates == 1 and run.iterations == 2 and calls["n"] == 2
    assert all(torch.isfinite(w).all() for w in _weights(run.checkpoint).values())


def test_shadow_in_pybullet_trains_too(tmp_path, clusters) -> None:
    run = _train(tmp_path / "run", clusters, "iterations=1", "hand=shadow", "sim=pybullet")
    data = read_checkpoint(run.checkpoint)
    assert (run.hand, run.sim, data["iter"]) == ("shadow", "pybullet", 1)
    assert data["ges"]["made_for"]["hand"] == "shadow" and len(data["ges"]["made_for"]["joint_names"]) == 24


def test_residual_critic_warmup_and_own_critic_fit(tmp_path, clusters) -> None:
    """``ppo.critic_warmup_iterations`` makes the first iterations critic-only without a warm start, and
    ``ppo.critic_fit_epochs`` fits the critic with its own optimizer on every later rollout: at a PPO rate of 1e-9
    the critic then still moves, and without the fit it does not (measurably)."""
    base = ["iterations=3", "action_mode=residual", "ppo.learning_rate=1e-9", "ppo.schedule=fixed"]
    moved = {}
    for name, extra in (("fit", ["ppo.critic_warmup_iterations=1", "ppo.critic_fit_epochs=2"]), ("plain", [])):
        out = tmp_path / name
        _train(out, clusters, *base, *extra)
        critic = [read_checkpoint(out / "checkpoints" / f"model_{i}.pt")["critic_state_dict"] for i in (2, 3)]
        moved[name] = max(float((critic[1][k] - critic[0][k]).abs().max()) for k in critic[0] if k.startswith("mlp."))
        rows = [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]
        updates = [r["update"] for r in rows]
        assert updates == (["critic", "ppo", "ppo"] if extra else ["ppo", "ppo", "ppo"])
    assert moved["fit"] > 1e-4 and moved["plain"] < 1e-6, moved


def _history(out) -> list[dict]:
    rows = [json.loads(line) for line in (out / "history.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("seconds", "collect_s", "learn_s")} for r in rows]


def test_in_run_evaluation_is_eval_experts_on_the_checkpoint_and_leaves_training_alone(tmp_path, clusters) -> None:
    """``evaluation.interval=2``: the noise-free policy's episodes before the first iteration and every 2 iterations
    are the cells ``ges eval-experts`` writes for that checkpoint (same seed and episodes; the highest rise of each
    episode compared, a continuous figure), and before the first iteration the residual's base expert's cells;
    the training itself is that of a run without evaluations; ``best.pt`` is the best evaluation's checkpoint; a
    resumed run compares against the stored best."""
    from ges_core.env.evaluate import BaselineConfig
    from ges_core.experts.choice import parse_expert
    from ges_core.experts.evaluate import evaluate_experts
    from ges_core.training.config import TrainConfig
    from ges_core.training.envs import env_config

    residual = ("action_mode=residual", "ppo.schedule=fixed", "ppo.learning_rate=1e-3")
    plain = _train(tmp_path / "plain", clusters, "iterations=4", *residual)
    out = tmp_path / "eval"
    run = _train(out, clusters, "iterations=4", *residual, "evaluation.interval=2", "evaluation.episodes=2",
                 "keep_checkpoints=9")  # fmt: skip
    assert _history(out) == _history(tmp_path / "plain")
    a, b = _weights(plain.checkpoint), _weights(run.checkpoint)
    assert all(torch.equal(a[k], b[k]) for k in a)

    rows = [json.loads(line) for line in (out / "evaluations.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == [0, 2, 4] and all(r["episodes"] == 4 for r in rows)  # 2 objects x 2
    for r in rows[1:]:  # against the starting policy (iteration 0), from the rows' own rates
        assert r["vs_start"]["points"] == round(100 * (r["success_paper"] - rows[0]["success_paper"]), 2)
    assert run.evaluation["objects"] == 2 and run.evaluation["last"] == rows[-1]["success_paper"]
    best = run.evaluation["best_iteration"]
    assert best == max(rows, key=lambda r: (r["success_paper"], -r["iteration"]))["iteration"]
    kept, stored = _weights(out / "checkpoints" / "best.pt"), _weights(out / "checkpoints" / f"model_{best}.pt")
    assert all(torch.equal(kept[k], stored[k]) for k in kept)

    cfg = TrainConfig.model_validate(read_checkpoint(run.checkpoint)["ges"]["train_config"])
    env = env_config(cfg)
    env = env.model_copy(update={"randomization": env.randomization.model_copy(update={"seed": 100})})
    config = BaselineConfig(hand="allegro", sim="sapien", envs=2, selection=cfg.selection, seed=100, env=env,
                            splits=("train",))  # fmt: skip
    column = parse_expert(f"it2=ppo:checkpoint={out / 'checkpoints' / 'model_2.pt'}")
    report = evaluate_experts(DATASET, config, [column], tmp_path / "matrix")
    cells = json.loads(report.path.read_text())["cells"]
    assert set(cells) == set(rows[1]["per_object"])
    for oid, cell in cells.items():
        it2 = cell["it2"]
        assert [it2["episodes"], it2["paper"], it2["peers"]] == rows[1]["per_object"][oid]
        assert it2["max_rise"] == rows[1]["max_rise"][oid] and max(it2["max_rise"]) > 0.01  # it moved the object
        base = cell["scripted"]  # the residual's starting policy is its base expert: iteration 0's row
        assert [base["episodes"], base["paper"], base["peers"]] == rows[0]["per_object"][oid]
        assert base["max_rise"] == rows[0]["max_rise"][oid]

    again = _train(out, clusters, "iterations=6", resume=True)
    rows = [json.loads(line) for line in (out / "evaluations.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == [0, 2, 4, 6]
    tops = [r["iteration"] for r in rows if r["success_paper"] == max(x["success_paper"] for x in rows)]
    assert again.evaluation["best_iteration"] == tops[0]  # a tie with the stored best keeps the earlier one
    assert read_checkpoint(again.checkpoint)["ges"]["state"]["evaluation"]["best_iteration"] == tops[0]


def test_evaluation_promotes_the_curriculum(tmp_path, clusters, capsys) -> None:
    """``ges train-expert --eval-every 1 -o curriculum.promote_on=evaluation``: the stages advance on the
    evaluation's success (the base expert holds these grasps), long before the iteration cap, and the log says so."""
    save_clusters(clusters, tmp_path / "clusters.json")
    extra = [*FAST, "action_mode=residual", "curriculum.max_iterations=50", "curriculum.promote_on=evaluation",
             "evaluation.episodes=1"]  # fmt: skip
    args = ["train-expert", DATASET, "--out", str(tmp_path / "run"), "--no-progress", "--clusters",
            str(tmp_path / "clusters.json"), "--iterations", "2", "--eval-every", "1"]  # fmt: skip
    assert main([*args, *(x for o in extra for x in ("-o", o))]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"evaluation \(noise-free, 2 object\(s\) x 1 episode\(s\)\): last [\d.]+ %, best [\d.]+ % at "
                     r"iteration \d -> .*best\.pt", printed)  # fmt: skip
    log = (tmp_path / "run" / "curriculum.log").read_text().splitlines()
    assert [line.split(",")[1].strip().split(":")[0] for line in log] == ["evaluation", "evaluation"]
    assert all("noise-free episode(s)" in line for line in log)


def test_a_run_killed_after_its_last_checkpoint_resumes_with_one_log_line_per_iteration(tmp_path, clusters) -> None:
    """A kill after iteration 4 was logged but before its checkpoint (here: the checkpoints of iterations 3 and 4
    removed, last.pt back at 2, and a history line cut short): --resume repeats iterations 3-4, and the run
    folder's logs hold one line per iteration and evaluation, those up to 2 as they were. (The repeated iterations
    restart their episodes, so they are not the killed run's: docs/training.md.)"""
    extra = ("action_mode=residual", "ppo.schedule=fixed", "ppo.learning_rate=1e-3", "evaluation.interval=2",
             "evaluation.episodes=1", "curriculum.max_iterations=3")  # fmt: skip
    out = tmp_path / "killed"
    _train(out, clusters, "iterations=4", *extra)
    before = {name: (out / name).read_text().splitlines() for name in ("history.jsonl", "evaluations.jsonl")}
    ckpts = out / "checkpoints"
    for n in (3, 4):
        (ckpts / f"model_{n}.pt").unlink()
    (ckpts / "last.pt").write_bytes((ckpts / "model_2.pt").read_bytes())
    with open(out / "history.jsonl", "a", encoding="utf-8") as fh:
        fh.write('{"iteration": 5, "env_st')  # the line being written when the process died
    again = _train(out, clusters, "iterations=4", resume=True)
    assert again.iterations == 4 and again.resumed_from.endswith("last.pt")
    history = (out / "history.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in history] == [1, 2, 3, 4] and history[:2] == before["history.jsonl"][:2]
    rows = (out / "evaluations.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in rows] == [0, 2, 4] and rows[:2] == before["evaluations.jsonl"][:2]
    log = (out / "curriculum.log").read_text().splitlines()
    assert [line.split(":")[0] for line in log] == ["iteration 3"]  # stage 1 -> 2 once, at the cap of 3 iterations
