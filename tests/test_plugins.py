"""Discovery: entry points, local plugins, blocking, duplicate names, broken plugins."""

from __future__ import annotations

import importlib.metadata
import sys

import pytest

from ges_core import __version__
from ges_core import plugins as plugin_mod
from ges_core.builtins import BUILTIN_PLUGINS
from ges_core.errors import PluginError, RegistrationError, UnknownNameError
from ges_core.registry import Registry, load_registry

LOCAL_HAND = """
from ges_core import hookimpl
from ges_core.specs import HandSpec

@hookimpl
def ges_register_hands(register):
    register(HandSpec(name="{name}", entry_point="x:y", description="local test hand"))
"""


def test_builtins_need_no_entry_points(monkeypatch):
    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: [])
    registry = load_registry()
    assert registry.names("hand") == ["allegro", "shadow"] and registry.names("sim") == ["pybullet", "sapien"]
    assert registry.spec("sim", "sapien").source == f"sapien (built-in, ges-unigrasp {__version__})"


def test_builtins_load_with_autoload_off():
    registry = load_registry(autoload=False)
    assert {"shadow", "allegro"} <= set(registry.names("hand"))
    assert {"sapien", "pybullet"} <= set(registry.names("sim"))
    assert all("built-in, ges-unigrasp" in spec.source for spec in registry.specs("sim"))


def test_a_builtin_can_be_blocked():
    registry = load_registry(blocked=("pybullet",))
    assert "pybullet" not in registry.names("sim") and "sapien" in registry.names("sim")


def test_builtin_failing_to_import_is_named(monkeypatch):
    monkeypatch.setitem(BUILTIN_PLUGINS, "broken", "ges_plugins.sims.no_such_plugin")
    with pytest.raises(PluginError) as err:
        plugin_mod.get_plugin_manager(autoload=False)
    msg = str(err.value)
    assert "built-in plugin 'broken' (ges_plugins.sims.no_such_plugin) failed to import: ModuleNotFoundError" in msg
    assert "--no-plugin broken" in msg and isinstance(err.value.__cause__, ModuleNotFoundError)
    assert plugin_mod.get_plugin_manager(autoload=False, blocked=["broken"]).has_plugin("sapien")


def test_local_plugin_by_file_path(write_registry, tmp_path):
    (tmp_path / "my_hand.py").write_text(LOCAL_HAND.format(name="my_hand"))
    registry = load_registry(write_registry("plugins: [my_hand.py]\n"))
    spec = registry.spec("hand", "my_hand")
    assert spec.description == "local test hand"
    assert "local" in spec.source


def test_local_plugin_by_dotted_module(write_registry, tmp_path, monkeypatch):
    (tmp_path / "lab_hands.py").write_text(LOCAL_HAND.format(name="lab_hand"))
    monkeypatch.syspath_prepend(str(tmp_path))
    registry = load_registry(write_registry("plugins: [lab_hands]\n"))
    assert "lab_hand" in registry.names("hand")
    sys.modules.pop("lab_hands", None)


def test_duplicate_name_names_both_sources(write_registry, tmp_path):
    (tmp_path / "dup.py").write_text(LOCAL_HAND.format(name="allegro"))
    with pytest.raises(RegistrationError) as err:
        load_registry(write_registry("plugins: [dup.py]\n"), autoload=False)
    msg = str(err.value)
    assert "'allegro'" in msg and "ges-unigrasp" in msg and "dup.py" in msg


def test_each_spec_is_credited_to_its_plugin(write_registry, tmp_path):
    for name in ("hand_a", "hand_b"):
        (tmp_path / f"{name}.py").write_text(LOCAL_HAND.format(name=name))
    registry = load_registry(write_registry("plugins: [hand_a.py, hand_b.py]\n"), autoload=False)
    assert registry.spec("hand", "hand_a").source == "local:hand_a.py (local)"
    assert registry.spec("hand", "hand_b").source == "local:hand_b.py (local)"


HOOK_OPTIONS = """
from ges_core import hookimpl
from ges_core.specs import HandSpec

calls = []

@hookimpl
def ges_register_sims():  # takes none of the spec's arguments: pluggy passes only what it asks for
    calls.append("sims")

@hookimpl(wrapper=True)
def ges_register_hands(register):
    calls.append("before")
    register(HandSpec(name="wrapped", entry_point="x:y"))
    result = yield
    calls.append("after")
    return result
"""


def test_hooks_are_called_through_pluggy(write_registry, tmp_path):
    """Hook options pluggy implements (argument selection, new-style wrappers) work in registration hooks."""
    (tmp_path / "options.py").write_text(HOOK_OPTIONS)
    registry = load_registry(write_registry("plugins: [options.py]\n"), autoload=False)
    (module,) = [p for name, p in registry.pm.list_name_plugin() if name == "local:options.py"]
    assert module.calls == ["before", "after", "sims"]
    assert registry.spec("hand", "wrapped").source == "local:options.py (local)"


def test_unknown_name_lists_known_and_suggests():
    registry = load_registry(autoload=False)
    with pytest.raises(UnknownNameError) as err:
        registry.spec("hand", "alegro")
    msg = str(err.value)
    assert "Did you mean 'allegro'" in msg and "shadow" in msg
    assert isinstance(err.value, KeyError)


def test_plugin_raising_on_import_is_named(write_registry, tmp_path):
    (tmp_path / "broken.py").write_text("raise RuntimeError('boom at import')\n")
    with pytest.raises(PluginError, match=r"local plugin 'broken.py'.*RuntimeError: boom at import"):
        load_registry(write_registry("plugins: [broken.py]\n"), autoload=False)


def test_missing_local_plugin_file(write_registry):
    with pytest.raises(PluginError, match="local plugin file 'nope.py' not found"):
        load_registry(write_registry("plugins: [nope.py]\n"), autoload=False)


def test_misspelled_hook_fails_at_check_pending(write_registry, tmp_path):
    (tmp_path / "typo.py").write_text(
        "from ges_core import hookimpl\n@hookimpl\ndef ges_register_hand(register):\n    pass\n"
    )
    with pytest.raises(PluginError, match="invalid hook"):
        load_registry(write_registry("plugins: [typo.py]\n"), autoload=False)


class _FakeEntryPoint:
    def __init__(self, name: str, dist_name: str, loader):
        self.name, self.group, self.value = name, plugin_mod.ENTRY_POINT_GROUP, f"{name}:x"
        self._loader = loader
        self.dist = type("D", (), {"metadata": {"name": dist_name}, "version": "9.9", "name": dist_name})()

    def load(self):
        return self._loader()


def test_third_party_entry_point_that_raises_is_named(monkeypatch):
    def boom():
        raise ImportError("no module named fancy_engine")

    fake = _FakeEntryPoint("fancy", "ges-fancy", boom)

    class _Dist:
        entry_points = (fake,)
        metadata = {"name": "ges-fancy"}
        version = "9.9"

    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: [fake])
    monkeypatch.setattr(importlib.metadata, "distributions", lambda: [_Dist()])
    with pytest.raises(PluginError) as err:
        plugin_mod.get_plugin_manager(autoload=True)
    msg = str(err.value)
    assert "plugin 'fancy' (package ges-fancy) failed to import" in msg and "--no-plugin fancy" in msg
    # blocking it lets everything else load
    pm = plugin_mod.get_plugin_manager(autoload=True, blocked=["fancy"])
    assert pm.is_blocked("fancy")


def test_entry_point_with_a_builtin_name_is_refused(monkeypatch):
    fake = _FakeEntryPoint("shadow", "ges-fake-shadow", lambda: pytest.fail("must not load"))
    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: [fake])
    with pytest.raises(
        PluginError, match="package ges-fake-shadow declares the plugin 'shadow', the name of a built-in"
    ):
        plugin_mod.get_plugin_manager(autoload=True)


def test_own_entry_points_of_an_older_install_are_ignored(monkeypatch):
    stale = _FakeEntryPoint("shadow", plugin_mod.OWN_DISTRIBUTION, lambda: pytest.fail("must not load"))
    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: [stale])
    assert plugin_mod.get_plugin_manager(autoload=True).has_plugin("shadow")


def test_two_packages_declaring_one_plugin_name(monkeypatch):
    eps = [_FakeEntryPoint("hands", "pkg-a", object), _FakeEntryPoint("hands", "pkg-b", object)]
    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: eps)
    with pytest.raises(PluginError, match="two packages declare the plugin 'hands': pkg-a and pkg-b"):
        plugin_mod.get_plugin_manager(autoload=True)


def test_autoload_off_skips_third_party(monkeypatch):
    fake = _FakeEntryPoint("fancy", "ges-fancy", lambda: pytest.fail("must not load"))
    monkeypatch.setattr(plugin_mod, "_entry_points", lambda: [fake])
    monkeypatch.setenv(plugin_mod.AUTOLOAD_ENV, "1")
    pm = plugin_mod.get_plugin_manager()
    assert not pm.has_plugin("fancy")


def test_each_registry_is_fresh():
    a, b = load_registry(autoload=False), load_registry(autoload=False)
    assert a.pm is not b.pm and isinstance(a, Registry)
