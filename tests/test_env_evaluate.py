"""Expert evaluation over Stage 1 grasps: real episodes (Allegro, SAPIEN, 2 envs), resume, errors, table, CLI."""

from __future__ import annotations

import json
import re
from collections import Counter

import pytest
import torch
from helpers_env import grasp_dataset

from ges_core.cli import main
from ges_core.config import parse_model
from ges_core.dataset import open_dataset
from ges_core.env.evaluate import (
    BaselineConfig,
    SplitRow,
    evaluate_baseline,
    format_table,
    results_path,
    summarize,
)
from ges_core.env.grasp_env import GraspEnv
from ges_core.env.grasp_source import load_grasp, select_records
from ges_core.env.success import EndReason
from ges_core.errors import AssetError, BackendUnavailable, ConfigError
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_plugins.experts.scripted.expert import ScriptedExpert

pytestmark = pytest.mark.sim
CANDIDATES = ("procedural/cube/000", "procedural/sphere/000", "procedural/box/000", "procedural/ellipsoid/000")
"""Primitives tried in order until Stage 1 has stored grasps for two (its verdicts change as Stage 1 evolves)."""
SHORT = {"episode_length": 15, "reach_steps": 5, "settle_steps": 0}
"""Episodes cut short (15 control steps): enough for the bookkeeping tests, not for a lift."""


class CountingRegistry:
    """A real registry that counts simulators built and can refuse to build them."""

    def __init__(self, refuse: bool = False, overrides: tuple[str, ...] = ()) -> None:
        self.real, self.refuse, self.sims = load_registry(overrides=overrides), refuse, 0

    def __getattr__(self, name):  # build_hand, build_expert, settings, spec: the real registry's
        return getattr(self.real, name)

    def build_sim(self, name, scene=None):
        if self.refuse:
            raise BackendUnavailable(f"{name}: refused by the test registry")
        self.sims += 1
        return self.real.build_sim(name, scene)


@pytest.fixture(scope="module")
def grown(tmp_path_factory) -> tuple:
    """(dataset folder, ids A and B of the two records holding grasps, sorted; records without one may be there)."""
    root = tmp_path_factory.mktemp("evaluate") / "ds"
    return root, tuple(sorted(grasp_dataset(root, CANDIDATES)))


@pytest.fixture(scope="module")
def dataset(grown):
    return grown[0]


@pytest.fixture(scope="module")
def pair(grown) -> tuple[str, str]:
    return grown[1]


@pytest.fixture(scope="module")
def full_run(dataset, tmp_path_factory):
    """Every stored grasp (selection 'any': the pair), full-length episodes, 2 envs."""
    out = tmp_path_factory.mktemp("baseline")
    config = BaselineConfig(hand="allegro", sim="sapien", envs=2, selection="any")
    return evaluate_baseline(dataset, config, out, registry=CountingRegistry()), out


def short_config(**kw) -> BaselineConfig:
    data = {"hand": "allegro", "sim": "sapien", "envs": 2, "selection": "any", "env": SHORT}
    return BaselineConfig.model_validate({**data, **kw})


def direct_episode(dataset, object_id: str, config: BaselineConfig, metrics: dict | None = None) -> tuple:
    """Reference: the same episode driven through GraspEnv alone (no VecEnv, no auto-reset): (end reasons, peers
    flags, steps). ``metrics``, if given, receives the Table 3 metrics recomputed from each env's velocity
    trajectory with the formulas of ges_core.env.metrics' docstring: name -> per env value."""
    registry = load_registry()
    hand = registry.build_hand(config.hand)
    asset, targets = load_grasp(
        dataset, object_id, hand.description, config.envs, selection="any", registry=registry, sim_name=config.sim
    )
    scene = parse_model(SceneConfig, open_dataset(dataset).run_config["scene"]).model_copy(
        update={"num_envs": config.envs}
    )
    with registry.build_sim(config.sim, scene) as sim:
        env = GraspEnv(sim, hand, asset, targets, config.env)
        torch.manual_seed(config.seed)
        env.reset_all()
        expert = ScriptedExpert(env.obs_layout, env.act_layout, hand=hand)  # as the plugin's build_expert
        obs, _ = env.observe()
        reasons, peers, steps = [None] * config.envs, [False] * config.envs, [0] * config.envs
        wrist_vel, joint_vel = [], []
        for t in range(1, config.env.episode_length + 1):
            unstable = env.apply_action(expert.act(obs))
            obs, state = env.observe()
            wrist_vel.append(state["wrist_vel"].double().clone()), joint_vel.append(state["dq"].double().clone())
            reason = env.end_reasons(state, torch.full((config.envs,), t >= config.env.episode_length), unstable)
            for i in range(config.envs):
                if reasons[i] is None and reason[i] != EndReason.RUNNING:
                    reasons[i] = EndReason(int(reason[i])).name.lower()
                    peers[i], steps[i] = bool(env.tracker.peer_success[i]), t
            if all(r is not None for r in reasons):
                break
        if metrics is not None:
            dt, w, q = env.control_dt, torch.stack(wrist_vel), torch.stack(joint_vel)  # (T, n, 6), (T, n, K)
            for name in ("arm_oscillation", "hand_oscillation", "fdc"):
                metrics[name] = []
            for i, t_end in enumerate(steps):
                wi, qi = w[:t_end, i], q[:t_end, i]  # the env's own episode: steps 1..t_end
                metrics["arm_oscillation"].append(float((wi[1:] - wi[:-1]).square().sum() / dt))
                metrics["hand_oscillation"].append(float((qi[1:] - qi[:-1]).square().sum() / dt))
                signs = torch.sign(qi[:, torch.as_tensor(env.groups)])  # (T, J, fingers)
                metrics["fdc"].append(float(-signs.var(dim=2, unbiased=False).sum()))
    return reasons, peers, steps


def test_episodes_match_a_direct_run_of_the_env(full_run, dataset, pair):
    report, _ = full_run
    assert [r["object_id"] for r in report.results] == list(pair) and sorted(report.evaluated) == list(pair)
    res = report.results[0]
    reference: dict = {}
    reasons, peers, steps = direct_episode(dataset, pair[0], report.config, reference)
    assert (res["end_reasons"], res["peers"], res["steps"]) == (reasons, peers, steps)
    for name, values in reference.items():  # Table 3 metrics: the VecEnv's running sums vs the whole trajectory
        assert res["metrics"][name] == pytest.approx(values, rel=1e-4, abs=1e-6), name
    assert min(res["metrics"]["arm_oscillation"]) > 0 and max(res["metrics"]["fdc"]) <= 0
    assert res["paper_success"] == reasons.count("success") and res["peers_success"] == sum(peers)
    for r in report.results:  # both envs run the same physics; the flags agree with the rise
        assert len(set(r["end_reasons"])) == 1 and len(set(r["max_rise"])) == 1 and "error" not in r
        for reason, peer, rise in zip(r["end_reasons"], r["peers"], r["max_rise"], strict=True):
            assert reason in ("success", "dropped", "not_lifted", "timeout", "unstable")
            assert rise >= 0.2 if reason == "success" else True
            assert rise >= 0.15 if peer else True  # within 5 cm of the point 0.2 m up
            assert rise < 0.03 if reason == "not_lifted" else True


def test_results_file_and_table_agree_with_the_results(full_run, dataset):
    report, out = full_run
    stored = json.loads(results_path(out, report.config).read_text())
    assert stored["format"] == "ges.baseline_results"
    assert [stored["objects"][r["object_id"]] for r in report.results] == report.results
    rows = {row.split: row for row in report.rows()}
    for row in rows.values():
        mine = [r for r in report.results if row.split in ("all", r["split"])]
        assert (row.objects, row.episodes) == (len(mine), 2 * len(mine))
        assert row.paper == sum(r["paper_success"] for r in mine) and row.peers == sum(r["peers_success"] for r in mine)
        assert sum(row.reasons.values()) == row.episodes
    considered = len(open_dataset(dataset))
    assert rows["all"].considered == considered
    table = report.table()
    assert "selection 'any' (any record holding a grasp and a pre-grasp" in table
    assert f"| all | 2/{considered} | 4 | {_pct(rows['all'].paper, 4)} | {_pct(rows['all'].peers, 4)} |" in table


def _pct(k: int, n: int) -> str:
    return f"{100 * k / n:.1f} % ({k}/{n})"


def test_rerun_reuses_stored_results_without_simulating(full_run, dataset, pair):
    report, out = full_run
    again = evaluate_baseline(dataset, report.config, out, registry=CountingRegistry(refuse=True))
    assert again.reused == list(pair) and again.evaluated == [] and again.results == report.results


def test_other_settings_are_refused_but_another_selection_reuses(full_run, dataset, pair):
    report, out = full_run
    other = report.config.model_copy(update={"envs": 3})
    with pytest.raises(ConfigError, match=r"were written with other settings \(config.envs: 2 -> 3\).*another --out"):
        evaluate_baseline(dataset, other, out, registry=CountingRegistry(refuse=True))
    validated = report.config.model_copy(update={"selection": "validated"})
    want = [r.object_id for r in select_records(open_dataset(dataset), "allegro", selection="validated").records]
    again = evaluate_baseline(dataset, validated, out, registry=CountingRegistry(refuse=True))
    assert want and again.evaluated == [] and again.reused == want
    assert again.results == [r for r in report.results if r["object_id"] in want]


def test_results_stored_before_the_expert_gained_a_setting_are_reused(full_run, dataset, tmp_path):
    """Results written before the scripted expert had finger_shift ran its default: reused, not refused; a stored
    value other than the default is a difference."""
    report, out = full_run
    stored = json.loads(results_path(out, report.config).read_text())
    assert stored["run"]["expert_defaults"].pop("finger_shift") == 0.0
    results_path(tmp_path, report.config).write_text(json.dumps(stored))
    again = evaluate_baseline(dataset, report.config, tmp_path, registry=CountingRegistry(refuse=True))
    assert again.evaluated == [] and again.results == report.results
    stored["run"]["expert_defaults"]["finger_shift"] = 0.01
    results_path(tmp_path, report.config).write_text(json.dumps(stored))
    with pytest.raises(ConfigError, match=r"other settings \(expert_defaults.finger_shift: 0.01 -> 0.0\)"):
        evaluate_baseline(dataset, report.config, tmp_path, registry=CountingRegistry(refuse=True))


def test_results_of_another_version_are_refused_and_kept(full_run, dataset, tmp_path):
    report, out = full_run
    source = results_path(out, report.config)
    stored = json.loads(source.read_text())
    copy = tmp_path / "other"
    results_path(copy, report.config).parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({**stored, "version": stored["version"] + 1})
    results_path(copy, report.config).write_text(text)
    with pytest.raises(AssetError, match=r"baseline results of version 2, this code reads 1.*another --out"):
        evaluate_baseline(dataset, report.config, copy, registry=CountingRegistry(refuse=True))
    assert results_path(copy, report.config).read_text() == text  # nothing overwritten


def test_killed_run_resumes_with_the_missing_object_only(dataset, pair, tmp_path):
    a, b = pair
    config = short_config()
    first = evaluate_baseline(dataset, config, tmp_path)
    assert first.evaluated == [a, b]
    path = results_path(tmp_path, config)
    data = json.loads(path.read_text())
    lost = data["objects"].pop(b)  # as if killed after the first object's write
    path.write_text(json.dumps(data))
    registry = CountingRegistry()
    second = evaluate_baseline(dataset, config, tmp_path, registry=registry)
    assert second.evaluated == [b] and second.reused == [a] and registry.sims == 2  # rest-pose scene + env
    redone = second.results[1]
    assert {k: v for k, v in redone.items() if k != "seconds"} == {k: v for k, v in lost.items() if k != "seconds"}
    assert set(json.loads(path.read_text())["objects"]) == {a, b}


def test_a_changed_grasp_is_evaluated_again_and_other_objects_stay_stored(dataset, pair, tmp_path):
    a, b = pair
    config = short_config()
    evaluate_baseline(dataset, config, tmp_path)
    path = results_path(tmp_path, config)
    data = json.loads(path.read_text())
    data["objects"][a]["grasp_key"] = "0" * 16
    data["objects"]["procedural/other/000"] = {"split": "train", "note": "outside this run's selection"}
    path.write_text(json.dumps(data))
    report = evaluate_baseline(dataset, config, tmp_path)
    assert report.evaluated == [a] and report.reused == [b]
    stored = json.loads(path.read_text())["objects"]
    assert set(stored) == {a, b, "procedural/other/000"} and stored[a]["grasp_key"] != "0" * 16


def test_a_changed_expert_default_invalidates_stored_results(full_run, dataset):
    report, out = full_run
    changed = CountingRegistry(refuse=True, overrides=("settings.expert.scripted.lift=0.5",))  # registry.yaml's
    with pytest.raises(ConfigError, match=r"expert_defaults.lift: [0-9.]+ -> 0.5"):
        evaluate_baseline(dataset, report.config, out, registry=changed)


def test_an_object_that_cannot_be_set_up_is_an_error_row(dataset, tmp_path):
    report = evaluate_baseline(dataset, short_config(), tmp_path, registry=CountingRegistry(refuse=True))
    for res in report.results:
        assert res["end_reasons"] == ["error", "error"] and res["paper_success"] == 0
        assert res["error"] == "BackendUnavailable: sapien: refused by the test registry"
    n = len(open_dataset(dataset))
    assert f"| all | 2/{n} | 4 | 0.0 % (0/4) | 0.0 % (0/4) | 4 |" in report.table()


def test_summarize_counts_per_split_and_all():
    results = [
        {"split": "train", "envs": 2, "paper_success": 1, "peers_success": 2, "end_reasons": ["success", "timeout"]},
        {"split": "unseen_category", "envs": 2, "paper_success": 0, "peers_success": 0,
         "end_reasons": ["dropped", "dropped"]},
    ]  # fmt: skip
    rows = {r.split: r for r in summarize(results, {"train": 3, "unseen_category": 1})}
    assert rows["train"].paper_rate == 0.5 and rows["train"].peers_rate == 1.0
    assert rows["unseen_object"].episodes == 0 and rows["unseen_object"].paper_rate is None
    assert rows["all"].reasons == Counter(success=1, timeout=1, dropped=2) and rows["all"].considered == 4
    table = format_table(list(rows.values()))
    assert "| unseen_object | 0/0 | 0 | - | - | 0 | 0 | 0 |" in table
    assert "| all | 2/4 | 4 | 25.0 % (1/4) | 50.0 % (2/4) | 1 | 2 | 1 |" in table
    assert isinstance(rows["all"], SplitRow) and rows["all"].to_dict()["end_reasons"]["dropped"] == 2


def test_config_rejects_unknown_selection_and_split():
    with pytest.raises(ValueError, match="unknown selection 'best'"):
        BaselineConfig(hand="allegro", sim="sapien", selection="best")
    with pytest.raises(ValueError, match=r"unknown splits \['test'\]"):
        BaselineConfig(hand="allegro", sim="sapien", splits=("test",))


def test_cli_prints_the_table_and_errors_in_one_line(dataset, tmp_path, capsys):
    args = ["env", "baseline", str(dataset), "--hand", "allegro", "--sim", "sapien", "--envs", "1",
            "--select", "any", "--out", str(tmp_path), "--no-progress"]  # fmt: skip
    for key, value in SHORT.items():
        args += ["-o", f"env.{key}={value}"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "scripted expert | hand allegro | sim sapien | grasps: selection 'any'" in out
    assert f"| all | 2/{len(open_dataset(dataset))} | 2 |" in out and "2 object(s) evaluated, 0 reused" in out
    assert main(["env", "baseline", str(dataset), "--hand", "shadow", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("ges: error: dataset") and "holds no record of hand 'shadow' (it holds: allegro)" in err
    assert "\n" not in err


def test_scripted_expert_refuses_nogoal(dataset, tmp_path):
    """The expert's own refusal (its factory), not an error row: the run stops at the first object."""
    config = short_config(env={**SHORT, "goal_prior": False})
    with pytest.raises(ConfigError, match=r"reads the goal blocks .* cannot run with env.goal_prior=false"):
        evaluate_baseline(dataset, config, tmp_path, registry=CountingRegistry())


def test_grasps_made_for_another_description_of_the_hand_are_warned_about(dataset, tmp_path, monkeypatch):
    """Stage 2 reads the hand the dataset's manifest describes (its hash and fields) and warns, naming each changed
    field, when the hand it builds (prepared, ``built_prepared``, as ges synth does) differs; the same dataset as
    made gives no warning. (With the cells refused by the registry, no simulator runs: the warning comes before the
    cells.)"""
    import shutil
    import warnings

    from ges_core.dataset.hands import HandChangedWarning
    from ges_core.env.evaluate import fanout

    built = []
    real = fanout.built_prepared
    monkeypatch.setattr(fanout, "built_prepared", lambda registry, name: built.append(name) or real(registry, name))

    with warnings.catch_warnings():
        warnings.simplefilter("error", HandChangedWarning)
        evaluate_baseline(dataset, short_config(), tmp_path / "same", registry=CountingRegistry(refuse=True))
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    stored = manifest["hands"]["allegro"]
    joint = next(k for k in stored["description"] if k.startswith("pd_stiffness["))
    stored["description"][joint], stored["hash"] = 123.0, "0" * 16  # as if Stage 1 had run with other gains
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.warns(HandChangedWarning, match=rf"hand 'allegro'.*{re.escape(joint)}: 123.0 -> 400.0.*ges synth"):
        evaluate_baseline(copy, short_config(), tmp_path / "changed", registry=CountingRegistry(refuse=True))
    assert built == ["allegro", "allegro"]  # once per evaluation
