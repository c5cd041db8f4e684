"""A run setting that a hand's own YAML settings replace for that hand is said, not silently dropped.

Stage 1's per-hand precedence is run config < the hand's YAML settings < ``hand_settings[hand]``
(:meth:`SynthesisConfig.for_hand`), so ``-o retarget.low_raise_height=0.01`` never reaches the Allegro, whose
YAML sets 0.02. Checked against ``for_hand`` itself (the value the hand's steps really get) and the shipped YAML.
"""

from __future__ import annotations

import logging

import pytest

from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run.pipeline import warn_shadowed_settings

OWN = {"retarget": {"low_raise_height": 0.02}, "sim_check": {"closure": 0.9}}


def _config(**data) -> SynthesisConfig:
    return SynthesisConfig.model_validate(data)


def test_a_run_value_the_hand_replaces_is_listed_with_both_values():
    config = _config(retarget={"low_raise_height": 0.01, "min_contact_height": 0.03})
    assert config.shadowed_by("allegro", OWN) == [("retarget.low_raise_height", 0.01, 0.02)]
    assert config.for_hand("allegro", OWN).retarget.low_raise_height == 0.02  # what the hand's steps really get
    assert config.for_hand("allegro", OWN).retarget.min_contact_height == 0.03  # a key the hand leaves alone


def test_nothing_is_listed_where_the_run_did_not_change_the_value_or_set_it_for_the_hand():
    assert _config().shadowed_by("allegro", OWN) == []  # the default: the hand's value is the intended one
    assert _config(retarget={"low_raise_height": 0.02}).shadowed_by("allegro", OWN) == []  # the same value
    per_hand = _config(retarget={"low_raise_height": 0.01}, hand_settings={"allegro": OWN | {"sim_check": {}}})
    assert per_hand.shadowed_by("allegro", OWN) == []  # set for that hand: it wins over the YAML
    assert per_hand.for_hand("allegro", OWN).retarget.low_raise_height == 0.02
    assert _config(retarget={"low_raise_height": 0.01}).shadowed_by("shadow", {}) == []  # a hand that sets nothing


def test_the_run_notes_each_setting_the_shipped_allegro_yaml_replaces(caplog):
    hand = load_registry().build_hand("allegro")
    own = hand.description.settings["retarget"]["low_raise_height"]
    assert own != 0.011
    config = _config(retarget={"low_raise_height": 0.011})
    with caplog.at_level(logging.WARNING):
        (note,) = warn_shadowed_settings(config, {"allegro": hand})
    assert f"hand 'allegro' sets retarget.low_raise_height={own} in its own settings, over this run's 0.011" in note
    assert "ges synth -o hand_settings.allegro.retarget.low_raise_height=0.011" in note
    assert "ges demo -o synthesis.hand_settings.allegro.retarget.low_raise_height=0.011" in note
    assert note in caplog.text
    assert warn_shadowed_settings(SynthesisConfig(), {"allegro": hand}) == []


@pytest.mark.sim
def test_run_synthesis_says_it_before_the_run(tmp_path, caplog):
    """The note comes from a real run (one object, no validation), before the dataset folder is written."""
    config = _config(
        library={"sources": ["procedural"], "procedural_count": 1},
        attempts=1,
        validate_sims=[],
        retarget={"low_raise_height": 0.011},
    )
    with caplog.at_level(logging.WARNING):
        run_synthesis(["procedural/box/000"], ["allegro"], config, tmp_path / "ds")
    assert "hand 'allegro' sets retarget.low_raise_height=" in caplog.text and "over this run's 0.011" in caplog.text
