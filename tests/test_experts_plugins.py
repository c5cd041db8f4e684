"""Experts are plugins: built by name through the registry (settings: plugin defaults, registry.yaml, the caller's),
unknown names and settings refused, and an expert made for another hand or layout refused naming both sides."""

from __future__ import annotations

import json
import sys

import pytest
import torch

from ges_core.cli import main
from ges_core.env.layout import ActionLayout, ObservationLayout
from ges_core.errors import ConfigError, PluginError, UnknownNameError
from ges_core.experts import parse_expert
from ges_core.experts.choice import ExpertChoice
from ges_core.policy import Expert, ExpertContext, ExpertScope, check_expert_fits
from ges_core.registry import load_registry
from ges_plugins.experts.scripted.config import ScriptedConfig
from ges_plugins.experts.scripted.expert import ScriptedExpert


def context(
    hand_name: str, *, goal: bool = True, wrist_step: float = 0.005, registry=None, wrist_rotation: str = "matrix"
) -> ExpertContext:
    """The context a GraspEnv of ``hand_name`` gives (its layouts built by the env's rule), without a simulator."""
    hand = (registry or load_registry()).build_hand(hand_name)
    d = hand.description
    links = tuple(dict.fromkeys([*d.tip_links, d.wrist.link]))
    lim = torch.as_tensor(d.limits_array)
    return ExpertContext(
        obs_layout=ObservationLayout.for_hand(d, links, goal, wrist_rotation),
        act_layout=ActionLayout(lim[:, 0], lim[:, 1], wrist_step, 0.1),
        hand=hand,
        num_envs=2,
    )


@pytest.fixture(scope="module")
def allegro() -> ExpertContext:
    return context("allegro")


# -- built by name ----------------------------------------------------------------------------------------------
def test_the_scripted_expert_is_built_by_name_with_its_registered_settings(allegro):
    registry = load_registry()
    assert "scripted" in registry.names("expert")
    spec = registry.spec("expert", "scripted")
    assert dict(spec.settings) == ScriptedConfig().model_dump()  # one source: the config model's defaults
    expert = registry.build_expert("scripted", allegro)
    assert isinstance(expert, ScriptedExpert) and isinstance(expert, Expert) and expert.made_for is None
    assert expert.close_steps == ScriptedConfig().close_steps and expert.hand is allegro.hand
    obs = torch.zeros(2, allegro.obs_layout.size)
    obs[:, allegro.obs_layout.slices["wrist_pose"]] = torch.tensor([0, 0, 0.2, 1, 0, 0, 0, 1, 0])  # identity rotation
    action = expert.act(obs)
    assert action.shape == (2, allegro.act_layout.size) and action.abs().max() <= 1.0


def test_settings_precedence_plugin_then_registry_yaml_then_caller(allegro):
    default = ScriptedConfig()
    yaml_set = load_registry(overrides=("settings.expert.scripted.close_steps=40", "settings.expert.scripted.lift=0.3"))
    built = yaml_set.build_expert("scripted", allegro)
    assert (built.close_steps, built.lift, built.pause_steps) == (40, 0.3, default.pause_steps)
    call = yaml_set.build_expert("scripted", allegro, close_steps=50)
    assert (call.close_steps, call.lift) == (50, 0.3)  # the caller's key wins, registry.yaml's other key stays
    text = parse_expert("scripted:close_steps=12,carry_gain=0.5").settings  # CLI text -> YAML-typed values
    built = load_registry().build_expert("scripted", allegro, **text)
    assert (built.close_steps, built.carry_gain, built.lift) == (12, 0.5, default.lift)


def test_unknown_expert_and_bad_settings_are_clear_errors(allegro):
    registry = load_registry()
    with pytest.raises(UnknownNameError, match=r"unknown expert 'scriptd'.*Did you mean 'scripted'"):
        registry.build_expert("scriptd", allegro)
    with pytest.raises(ConfigError, match=r"settings of expert 'scripted'.*bogus"):
        registry.build_expert("scripted", allegro, bogus=1)
    with pytest.raises(ConfigError, match=r"settings of expert 'scripted'.*close_steps"):
        registry.build_expert("scripted", allegro, close_steps=0)
    with pytest.raises(ConfigError, match=r"reads the goal blocks .* cannot run with env.goal_prior=false"):
        registry.build_expert("scripted", context("allegro", goal=False, registry=registry))


# -- made for one hand and layout -------------------------------------------------------------------------------
def test_a_scope_survives_json_and_fits_its_own_context(allegro):
    scope = ExpertScope.of(allegro)
    again = ExpertScope.from_dict(json.loads(json.dumps(scope.to_dict())))
    assert again == scope
    check_expert_fits(again, allegro)  # no error
    assert scope.hand == "allegro" and len(scope.joint_names) == allegro.act_layout.size - 6
    assert sum(n for _, n in scope.observation) == allegro.obs_layout.size
    with pytest.raises(ConfigError, match=r"checkpoint x: not an expert scope .*joint_names"):
        ExpertScope.from_dict({"hand": "allegro"}, where="checkpoint x")


def test_mismatch_names_both_sides(allegro):
    scope = ExpertScope.of(allegro)
    shadow = context("shadow")
    with pytest.raises(ConfigError) as err:
        check_expert_fits(scope, shadow, who="checkpoint runs/e1/model_10.pt")
    msg = str(err.value)
    assert msg.startswith("checkpoint runs/e1/model_10.pt was made for hand 'allegro'")
    assert "this environment has hand 'shadow'" in msg and "hand 'allegro' vs 'shadow'" in msg
    assert f"q {allegro.obs_layout.sizes()['q']} vs {shadow.obs_layout.sizes()['q']}" in msg
    assert "action joints 16 [" in msg and "24 [" in msg
    with pytest.raises(ConfigError, match=r"goal_q only in the expert's") as err:
        check_expert_fits(scope, context("allegro", goal=False))
    assert err.value.problems == ["observation blocks (goal_pos only in the expert's; goal_rot only in the "
                                  "expert's; goal_q only in the expert's)"]  # fmt: skip
    with pytest.raises(ConfigError, match=r"max_wrist_step 0.005 vs 0.01"):
        check_expert_fits(scope, context("allegro", wrist_step=0.01))


@pytest.mark.parametrize(("made", "env"), [("rotvec", "matrix"), ("matrix", "rotvec")])
def test_a_wrist_rotation_mismatch_names_the_setting_that_fits(made: str, env: str):
    """A checkpoint from before the matrix form (its wrist_pose 6 floats) in today's default env, and the reverse:
    the error names the block's sizes and the one setting that makes the env fit the expert."""
    scope = ExpertScope.of(context("allegro", wrist_rotation=made))
    sizes = {"matrix": 9, "rotvec": 6}
    with pytest.raises(
        ConfigError, match=rf"wrist_pose {sizes[made]} vs {sizes[env]}\b.*-o env.wrist_rotation={made}$"
    ):
        check_expert_fits(scope, context("allegro", wrist_rotation=env), who="checkpoint old.pt")
    check_expert_fits(scope, context("allegro", wrist_rotation=made))
    with pytest.raises(ConfigError) as other:  # another difference alone: no wrist hint
        check_expert_fits(scope, context("allegro", wrist_rotation=made, wrist_step=0.01))
    assert "env.wrist_rotation=" not in str(other.value)


PLUGIN = """
from ges_core import hookimpl
from ges_core.specs import ExpertSpec

@hookimpl
def ges_register_experts(register):
    register(ExpertSpec(name="fixed", entry_point="reg_experts_impl:fixed", settings={"scope": None},
                        made_for="reg_experts_impl:made_for"))
    register(ExpertSpec(name="wrong", entry_point="reg_experts_impl:wrong"))
"""
IMPL = """
import torch
from ges_core.policy import Expert, ExpertScope

class Fixed(Expert):
    name = "fixed"
    def __init__(self, context, scope):
        self.made_for, self.size = ExpertScope.from_dict(scope), context.act_layout.size
    def act(self, obs):
        return torch.zeros(obs.shape[0], self.size)

def fixed(context, scope=None):
    return Fixed(context, scope)

def wrong(context):
    return "not an expert"

def made_for(settings):
    return ExpertScope.from_dict(settings["scope"]) if settings["scope"] else None
"""


@pytest.fixture
def registry_with(tmp_path, write_registry, monkeypatch):
    """A registry holding a test expert 'fixed' (made for the scope given in its settings, as a checkpoint is)."""
    (tmp_path / "reg_experts_impl.py").write_text(IMPL)
    (tmp_path / "reg_experts.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield lambda extra="": load_registry(write_registry("plugins: [reg_experts.py]\n" + extra), autoload=False)
    sys.modules.pop("reg_experts_impl", None)


def test_the_registry_refuses_an_expert_made_for_another_hand(registry_with, allegro):
    registry = registry_with()
    scope = ExpertScope.of(allegro).to_dict()
    assert registry.build_expert("fixed", allegro, scope=scope).made_for.hand == "allegro"
    with pytest.raises(ConfigError, match=r"expert 'fixed' was made for hand 'allegro'.*has hand 'shadow'"):
        registry.build_expert("fixed", context("shadow", registry=registry), scope=scope)
    with pytest.raises(PluginError, match=r"expert plugin 'wrong' .* returned str, not an Expert"):
        registry.build_expert("wrong", allegro)


def test_the_hand_an_evaluation_runs_comes_from_the_experts_made_for_one(registry_with, allegro):
    """``experts_hand``: read from each expert's ``made_for`` without building it (a checkpoint's scope; here the
    test expert's setting): their one hand, --hand checked against it, experts of two hands refused, and None where
    no expert is made for a hand (the scripted one: any hand)."""
    from ges_core.experts.made_for import experts_hand

    registry = registry_with()
    made = {h: ExpertScope.of(c).to_dict() for h, c in (("allegro", allegro), ("shadow", context("shadow")))}
    mine = ExpertChoice("mine", "fixed", {"scope": made["allegro"]})
    theirs = ExpertChoice("theirs", "fixed", {"scope": made["shadow"]})
    script = ExpertChoice("scripted", "scripted")
    assert registry.expert_scope("scripted") is None and registry.expert_scope("fixed") is None
    assert registry.expert_scope("fixed", scope=made["shadow"]).hand == "shadow"
    assert experts_hand(registry, [script, mine], None) == "allegro"
    assert experts_hand(registry, [script, mine], "allegro") == "allegro"
    assert experts_hand(registry, [script], None) is None and experts_hand(registry, [script], "shadow") == "shadow"
    with pytest.raises(ConfigError, match=r"--hand shadow: expert\(s\) made for another hand: 'mine' for 'allegro'"):
        experts_hand(registry, [script, mine], "shadow")
    with pytest.raises(ConfigError, match=r"different hands \('mine' for 'allegro', 'theirs' for 'shadow'\)"):
        experts_hand(registry, [mine, theirs], None)


# -- choosing experts on the command line -----------------------------------------------------------------------
def test_expert_text_forms_and_errors():
    assert parse_expert("scripted").label == "scripted" and parse_expert("scripted").settings == {}
    slow = parse_expert("slow=scripted:close_steps=60,lift=0.25")
    assert (slow.label, slow.name, slow.settings) == ("slow", "scripted", {"close_steps": 60, "lift": 0.25})
    ppo = parse_expert("ppo:checkpoint=runs/a/model_10.pt")
    assert ppo.settings == {"checkpoint": "runs/a/model_10.pt"} and ppo.label == "ppo:checkpoint=runs/a/model_10.pt"
    assert parse_expert(ppo.text()) == ppo
    with pytest.raises(ConfigError, match=r"setting 'lift' must look like key=value"):
        parse_expert("scripted:lift")
    with pytest.raises(ConfigError, match=r"setting 'lift' is given twice"):
        parse_expert("scripted:lift=1,lift=2")
    with pytest.raises(ConfigError, match=r"the label 'a b' may hold"):
        parse_expert("a b=scripted")


def test_ges_list_and_info_show_the_expert(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "experts:" in out and "scripted" in out.split("experts:")[1]
    assert main(["info", "expert", "scripted"]) == 0
    out = capsys.readouterr().out
    assert "expert 'scripted'" in out and f"close_steps={ScriptedConfig().close_steps}" in out


def test_ges_env_baseline_takes_an_expert_by_name(capsys, tmp_path):
    args = ["env", "baseline", str(tmp_path), "--hand", "allegro", "--sim", "sapien", "--expert"]
    assert main([*args, "scriptd:lift=0.1"]) == 1  # refused before the dataset is opened
    assert "unknown expert 'scriptd'. Did you mean 'scripted'?" in capsys.readouterr().err
    assert main([*args, "scripted:lift"]) == 1
    assert "setting 'lift' must look like key=value" in capsys.readouterr().err
