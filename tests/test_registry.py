"""Building plugins by name: settings (the plugin's defaults, then registry.yaml) and factory failures."""

from __future__ import annotations

import sys

import pytest

from ges_core.errors import AssetError, PluginError
from ges_core.registry import load_registry

from conftest import REPO

FACTORIES = """
from ges_core.errors import AssetError

def strict(*, scale=1.0, mode="a"):
    return (scale, mode)

def buggy(**settings):
    return len(1)

def asset_missing(**settings):
    raise AssetError("hand 'asset' needs its mesh: reinstall it")
"""

PLUGIN = """
from ges_core import hookimpl
from ges_core.specs import HandSpec

@hookimpl
def ges_register_hands(register):
    register(HandSpec(name="strict", entry_point="reg_factories:strict"))
    register(HandSpec(name="tuned", entry_point="reg_factories:strict", settings={"scale": 2.0, "mode": "b"}))
    register(HandSpec(name="buggy", entry_point="reg_factories:buggy"))
    register(HandSpec(name="asset", entry_point="reg_factories:asset_missing"))
"""


@pytest.fixture
def registry_with(tmp_path, write_registry, monkeypatch):
    """A registry with the test hands above and extra registry.yaml text."""
    (tmp_path / "reg_factories.py").write_text(FACTORIES)
    (tmp_path / "reg_hands.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield lambda extra="": load_registry(write_registry("plugins: [reg_hands.py]\n" + extra), autoload=False)
    sys.modules.pop("reg_factories", None)


def test_spec_settings_are_defaults_that_registry_yaml_overrides(registry_with):
    assert registry_with().settings("hand", "tuned") == {"scale": 2.0, "mode": "b"}
    registry = registry_with("settings:\n  hand:\n    tuned: {mode: c}\n")
    assert registry.settings("hand", "tuned") == {"scale": 2.0, "mode": "c"}
    assert registry.settings("hand", "strict") == {}


def test_settings_that_do_not_fit_the_factory(registry_with):
    registry = registry_with("settings:\n  hand:\n    strict: {bogus: 1}\n")
    with pytest.raises(PluginError) as err:
        registry.build_hand("strict")
    msg = str(err.value)
    assert (
        msg.startswith("hand 'strict' rejected its settings ['bogus']:")
        and "unexpected keyword argument 'bogus'" in msg
    )
    assert "settings.hand.strict in registry.yaml" in msg


def test_type_error_inside_a_factory_is_a_plugin_bug(registry_with):
    with pytest.raises(PluginError) as err:
        registry_with().build_hand("buggy")
    msg = str(err.value)
    assert "hand plugin 'buggy' (local:reg_hands.py (local)) failed while building: TypeError:" in msg
    assert "rejected its settings" not in msg and "bug in the plugin" in msg
    assert isinstance(err.value.__cause__, TypeError) and err.value.plugin == "buggy"


def test_factory_errors_of_our_own_kind_pass_unchanged(registry_with):
    with pytest.raises(AssetError, match="hand 'asset' needs its mesh"):
        registry_with().build_hand("asset")


def test_factory_returning_the_wrong_type(registry_with):
    with pytest.raises(PluginError, match="hand plugin 'strict' .* returned tuple, not a HandModel"):
        registry_with().build_hand("strict")


@pytest.mark.parametrize("registry_yaml", ["", "shipped"])
def test_builtin_sims_carry_their_tuned_settings(write_registry, registry_yaml):
    """The tuned values come with the plugins, so a wheel without this checkout's registry.yaml gets them."""
    path = REPO / "registry.yaml" if registry_yaml == "shipped" else write_registry("")
    registry = load_registry(path, autoload=False)
    assert registry.settings("sim", "pybullet") == {"solver_iterations": 100, "friction_anchors": "on_touch"}
    assert registry.settings("sim", "sapien") == {"contact_offset": 0.002}


BUILTINS = [("hand", "allegro"), ("hand", "shadow"), ("sim", "pybullet"), ("sim", "sapien")]


@pytest.mark.parametrize("kind, name", BUILTINS)
def test_builtin_tuned_settings_fit_their_factories_annotations(kind, name):
    """Settings are validated against the factory's annotations before the call: the shipped values pass unchanged."""
    from ges_core.registry import _check_settings
    from ges_core.sim import SceneConfig

    registry = load_registry(REPO / "registry.yaml", autoload=False)
    spec = registry.spec(kind, name)
    settings = registry.settings(kind, name)
    args = (SceneConfig(),) if kind == "sim" else ()
    assert _check_settings(spec, spec.load(), args, dict(settings)) == settings
