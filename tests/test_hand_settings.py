"""Per-hand Stage 1 settings: the hand YAML's ``settings:``, the run's ``hand_settings``, their precedence, the
pipeline using them (contacts shared or not) and the scripted expert reading the hand's squeeze."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.config import parse_model
from ges_core.dataset import open_dataset
from ges_core.errors import AssetError, ConfigError, UnknownNameError
from ges_core.hand_settings import hand_sim_check_config, hand_train_config, hand_validate_config, merge_settings
from ges_core.hand_yaml import description_from_yaml
from ges_core.synthesis import SynthesisConfig, ValidateConfig, run_synthesis
from ges_core.synthesis.run import worker
from ges_core.synthesis.run.tasks import RegistrySpec

from helpers_sim import ALLEGRO_YAML, allegro_urdf_source

SETTINGS = """
settings:
  validate: {min_squeeze: 0.3, min_tips: 3}
  contacts: {max_width: 0.09}
  retarget: {wrist_search: {yaw_deg: [-20.0, 0.0, 20.0]}}
  thumb_keep: 2
"""


def _allegro(extra: str = "", **overrides):
    return description_from_yaml(
        ALLEGRO_YAML + extra, allegro_urdf_source().read_text(), source="my_allegro.yaml", **overrides
    )


def test_yaml_settings_are_read_and_kept_partial():
    d = _allegro(SETTINGS)
    assert d.settings == {
        "validate": {"min_squeeze": 0.3, "min_tips": 3},
        "contacts": {"max_width": 0.09},
        "retarget": {"wrist_search": {"yaw_deg": [-20.0, 0.0, 20.0]}},
        "thumb_keep": 2,
    }
    assert _allegro().settings == {}


@pytest.mark.parametrize(
    ("settings", "path"),
    [
        ("settings: {validate: {min_squez: 0.3}}", "settings.validate.min_squez"),
        ("settings: {validate: {min_tips: 0}}", "settings.validate.min_tips"),
        ("settings: {contacts: {max_width: wide}}", "settings.contacts.max_width"),
        ("settings: {retarget: {wrist_search: {nonsense: 1}}}", "settings.retarget.wrist_search.nonsense"),
        ("settings: {squeeze: {force: 3}}", "settings.squeeze"),
        ("settings: {scene: {hand_friction: 1.0}}", "settings.scene"),
        ("settings: {thumb_keep: -1}", "settings.thumb_keep"),
        ("settings: {validate: 3}", "settings.validate"),
        ("settings: {sim_check: {closure: 1.5}}", "settings.sim_check.closure"),
        ("settings: {sim_check: {hand: shadow}}", "settings.sim_check.hand"),
        ("settings: {train: {residual_scale: 0}}", "settings.train.residual_scale"),
        ("settings: {train: {num_envs: 4}}", "settings.train.num_envs"),
        ("settings: {train: 0.02}", "settings.train"),
    ],
)
def test_bad_yaml_settings_name_the_file_and_the_dotted_path(settings, path):
    with pytest.raises(AssetError) as err:
        _allegro("\n" + settings + "\n")
    assert path in str(err.value)
    assert "my_allegro.yaml" in str(err.value) and "hand 'allegro_test'" in str(err.value)


def test_precedence_run_then_hand_yaml_then_hand_settings():
    hand = _allegro(SETTINGS).settings
    run = parse_model(
        SynthesisConfig,
        {
            "validate": {"min_squeeze": 0.1, "squeeze_force": 4.0, "hold_fraction": 0.8},
            "hand_settings": {"allegro": {"validate": {"min_tips": 4}}},
        },
    )
    cfg = run.for_hand("allegro", hand)
    assert cfg.validate_.min_squeeze == 0.3  # hand YAML over the run
    assert cfg.validate_.min_tips == 4  # hand_settings over the hand YAML
    assert cfg.validate_.squeeze_force == 4.0 and cfg.validate_.hold_fraction == 0.8  # the run's where neither sets
    assert cfg.contacts.max_width == 0.09 and cfg.contacts.min_width == run.contacts.min_width
    assert cfg.thumb_keep == 2 and cfg.retarget.wrist_search.yaw_deg == (-20.0, 0.0, 20.0)  # a list replaces
    assert cfg.retarget.wrist_search.model_dump(exclude={"yaw_deg"}) == run.retarget.wrist_search.model_dump(
        exclude={"yaw_deg"}
    )  # a nested section merges key by key
    other = run.for_hand("shadow", {})  # hand_settings of another hand does not leak
    assert other is run


def test_a_hand_that_sets_nothing_runs_with_the_run_config_and_its_hash_is_unchanged():
    run = SynthesisConfig()
    assert run.for_hand("allegro", {}) is run
    assert "hand_settings" not in run.dump()  # the stored run_config (and its hash) as before per-hand settings
    with_some = parse_model(SynthesisConfig, {"hand_settings": {"shadow": {"validate": {"min_squeeze": 0.2}}}})
    assert with_some.dump()["hand_settings"] == {"shadow": {"validate": {"min_squeeze": 0.2}}}


def test_bad_hand_settings_and_bad_merges_are_config_errors():
    with pytest.raises(ConfigError, match=r"hand_settings\.shadow\.validate\.min_squez"):
        parse_model(SynthesisConfig, {"hand_settings": {"shadow": {"validate": {"min_squez": 0.4}}}})
    with pytest.raises(ConfigError, match=r"settings of hand 'shadow'.*min_width"):
        SynthesisConfig().for_hand("shadow", {"contacts": {"max_width": 0.004}})  # below the run's min_width


def test_hand_settings_of_an_unknown_hand_is_refused_before_the_run(tmp_path):
    cfg = parse_model(SynthesisConfig, {"hand_settings": {"shadw": {"validate": {"min_squeeze": 0.2}}}})
    with pytest.raises(UnknownNameError, match=r"shadw.*hand_settings.*shadow"):
        run_synthesis(["procedural/box/000"], ["shadow"], cfg, tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_merge_settings_replaces_lists_and_merges_mappings():
    base = {"a": {"b": 1, "c": [1, 2]}, "d": 3}
    assert merge_settings(base, {"a": {"c": [5]}}, None, {"a": {"e": 2}}) == {"a": {"b": 1, "c": [5], "e": 2}, "d": 3}
    assert base == {"a": {"b": 1, "c": [1, 2]}, "d": 3}  # not modified


def test_scripted_expert_reads_the_hands_squeeze():
    from ges_plugins.experts.scripted.expert import ScriptedExpert

    class _Hand:
        def __init__(self, description):
            self.description = description

    plain, squeezing = _allegro(), _allegro("\nsettings: {validate: {squeeze_force: 2.5, max_squeeze: 0.9}}\n")
    assert hand_validate_config(plain) == ValidateConfig()
    expert = ScriptedExpert(None, None, hand=_Hand(squeezing))
    assert (expert.squeeze_force, expert.squeeze.max_squeeze) == (2.5, 0.9)
    assert expert.squeeze.min_squeeze == ValidateConfig().min_squeeze
    assert ScriptedExpert(None, None, hand=_Hand(squeezing), squeeze_force=7.0).squeeze_force == 7.0  # explicit wins
    assert ScriptedExpert(None, None, hand=_Hand(plain)).squeeze_force == ValidateConfig().squeeze_force


# -- the pipeline: contacts per distinct contact setting ---------------------------------------------------------
FAST = {"robust": {"enabled": False}, "validate_sims": [], "attempts": 1}
"""One object through contacts, retargeting and refinement only (a few seconds)."""


def _run(tmp_path, name: str, monkeypatch, overrides: tuple[str, ...] = ()) -> tuple[int, dict]:
    calls = []
    real = worker.generate_contacts

    def counting(*args, **kwargs):
        calls.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(worker, "generate_contacts", counting)
    cfg = parse_model(SynthesisConfig, FAST)
    run_synthesis(
        ["procedural/box/000"], ["allegro", "shadow"], cfg, tmp_path / name, registry=RegistrySpec(overrides=overrides)
    )
    data = open_dataset(tmp_path / name)
    return len(calls), {h: data.get("procedural/box/000", h) for h in ("allegro", "shadow")}


def test_contacts_are_shared_when_equal_and_generated_per_hand_when_not(tmp_path, monkeypatch):
    shared_calls, shared = _run(tmp_path, "shared", monkeypatch)
    assert shared_calls == 1
    for field in ("positions", "normals"):
        assert np.array_equal(getattr(shared["allegro"].contacts, field), getattr(shared["shadow"].contacts, field))
    spaced = ("settings.hand.allegro.settings={contacts: {finger_spacing: 0.03}}",)
    own_calls, own = _run(tmp_path, "own", monkeypatch, spaced)
    assert own_calls == 2
    moved = np.abs(own["allegro"].contacts.positions - shared["allegro"].contacts.positions).max()
    assert moved > 1e-3  # 3 cm spacing instead of 2 cm: the allegro's fingers sit elsewhere
    for field in ("positions", "normals"):  # the other hand keeps the contacts it had
        assert np.array_equal(getattr(own["shadow"].contacts, field), getattr(shared["shadow"].contacts, field))


def test_a_hands_validation_settings_reach_its_validation(tmp_path):
    """Allegro (4 fingertips) asked for 5 touching tips can never pass; the same grasp passes with the defaults."""
    cfg = parse_model(SynthesisConfig, {"robust": {"enabled": False}, "attempts": 1})
    run_synthesis(["procedural/box/000"], ["allegro"], cfg, tmp_path / "plain")
    strict = RegistrySpec(overrides=("settings.hand.allegro.settings={validate: {min_tips: 5}}",))
    run_synthesis(["procedural/box/000"], ["allegro"], cfg, tmp_path / "strict", registry=strict)
    plain, tight = (open_dataset(tmp_path / n).get("procedural/box/000", "allegro") for n in ("plain", "strict"))
    assert plain.steps["validation"].ok
    assert not tight.steps["validation"].ok and tight.steps["validation"].reason == "palm_only"
    assert np.array_equal(plain.grasp.q, tight.grasp.q)  # the same grasp: only the pass mark differs


def test_a_hands_sim_check_closure_is_used_unless_the_command_gives_one():
    """``settings.sim_check`` sets how ``ges sim check`` closes the hand; a value the user gives wins, and Stage 1's
    config ignores the section (it is not a SynthesisConfig section)."""
    from ges_core.config import load_config
    from ges_core.sim_check import SimCheckConfig

    d = _allegro("\nsettings: {sim_check: {closure: 0.3, lift_steps: 60}, validate: {min_tips: 3}}\n")
    mine = hand_sim_check_config(d, load_config(SimCheckConfig, None, []))
    assert (mine.closure, mine.lift_steps, mine.close_steps) == (0.3, 60, SimCheckConfig().close_steps)
    given = hand_sim_check_config(d, load_config(SimCheckConfig, None, ["closure=0.5"]))
    assert (given.closure, given.lift_steps) == (0.5, 60)
    assert hand_sim_check_config(_allegro(), SimCheckConfig()) == SimCheckConfig()
    stage1 = SynthesisConfig().for_hand("allegro_test", d.settings)
    assert stage1.validate_.min_tips == 3


def test_a_hands_train_settings_fill_only_what_the_run_leaves_unset():
    """``settings.train`` gives Stage 2 a hand's residual scale; a preset, --config or -o value wins, a resumed run's
    stored config keeps its own, Stage 1 ignores the section and the dataset hash does not see it."""
    from ges_core.dataset.hands import describe_hand
    from ges_core.training.config import TrainConfig, load_train_config

    d = _allegro("\nsettings: {train: {residual_scale: 0.02}, validate: {min_tips: 3}}\n")
    mine = hand_train_config(d, load_train_config("tiny", overrides=["action_mode=residual"]))
    assert mine.residual_scale == 0.02 and mine.action_mode == "residual" and mine.preset == "tiny"
    assert mine.num_envs == load_train_config("tiny").num_envs  # the rest of the preset as it was
    given = hand_train_config(d, load_train_config("tiny", overrides=["residual_scale=0.1"]))
    assert given.residual_scale == 0.1
    stored = TrainConfig.model_validate(TrainConfig().model_dump(mode="json"))  # how a resumed run rebuilds it
    assert hand_train_config(d, stored).residual_scale == TrainConfig().residual_scale
    plain = load_train_config("tiny")
    assert hand_train_config(_allegro(), plain) is plain
    assert SynthesisConfig().for_hand("allegro_test", d.settings).validate_.min_tips == 3
    without = _allegro("\nsettings: {validate: {min_tips: 3}}\n")
    assert describe_hand(d) == describe_hand(without)  # no record changes with it: datasets keep the hand
    assert describe_hand(d) != describe_hand(_allegro("\nsettings: {validate: {min_tips: 4}}\n"))
