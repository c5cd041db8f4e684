"""Specs load their factory lazily; every way that import can fail names the plugin and what to do."""

from __future__ import annotations

import sys

import pytest

from ges_core.errors import BackendUnavailable, PluginError
from ges_core.specs import HandSpec, SimSpec


@pytest.fixture
def modules(tmp_path, monkeypatch):
    """Write importable modules into a folder on sys.path; they are forgotten afterwards."""
    monkeypatch.syspath_prepend(str(tmp_path))
    written: list[str] = []

    def write(name: str, text: str) -> None:
        (tmp_path / f"{name}.py").write_text(text)
        written.append(name)

    yield write
    for name in written:
        sys.modules.pop(name, None)


def test_factory_loads_lazily(modules):
    modules("spec_ok_factory", "def make(**settings):\n    return settings\n")
    spec = HandSpec(name="ok", entry_point="spec_ok_factory:make")
    assert "spec_ok_factory" not in sys.modules
    assert spec.load()(a=1) == {"a": 1}


def test_missing_engine_says_what_to_install():
    spec = SimSpec(
        name="fancy", entry_point="x:y", requires=("no_such_engine_xyz",), install="pip install 'ges-x[fancy]'"
    )
    assert spec.missing() == ["no_such_engine_xyz"]
    with pytest.raises(BackendUnavailable, match=r"sim 'fancy' needs 'no_such_engine_xyz', not installed here: pip "):
        spec.load()


def test_missing_engine_without_an_install_hint():
    spec = HandSpec(name="h", entry_point="x:y", requires=("no_such_engine_xyz", "sys"))
    with pytest.raises(BackendUnavailable, match="needs 'no_such_engine_xyz', not installed here: install the package"):
        spec.load()


def test_engine_that_fails_its_own_import_is_unavailable(modules):
    """find_spec sees the engine, its import still fails for want of itself (a broken install)."""
    modules(
        "spec_half_engine",
        "raise ModuleNotFoundError(\"No module named 'spec_half_engine'\", name='spec_half_engine')\n",
    )
    modules("spec_uses_engine", "import spec_half_engine\n")
    spec = SimSpec(name="half", entry_point="spec_uses_engine:make", requires=("spec_half_engine",), install="pip x")
    with pytest.raises(BackendUnavailable, match="sim 'half' needs 'spec_half_engine', not installed here: pip x"):
        spec.load()


def test_factory_module_raising_on_import_is_named(modules):
    modules("spec_broken_factory", "raise RuntimeError('boom at import')\n")
    spec = HandSpec(name="broken", entry_point="spec_broken_factory:make", source="broken (local)")
    with pytest.raises(PluginError) as err:
        spec.load()
    assert str(err.value).startswith(
        "hand 'broken' (broken (local)) failed to import spec_broken_factory:make: RuntimeError: boom at import."
    )
    assert err.value.plugin == "broken" and isinstance(err.value.__cause__, RuntimeError)


def test_missing_module_that_is_not_an_engine_is_a_plugin_error():
    spec = HandSpec(name="typo", entry_point="no_such_module_xyz.hand:make")
    with pytest.raises(PluginError, match="hand 'typo' failed to import no_such_module_xyz.hand:make: ModuleNotFound"):
        spec.load()


@pytest.mark.parametrize(
    ("target", "message"),
    [("no_colon_here", "must look like 'package.module:Attr'"), ("sys:no_such_attr", "module 'sys' has no")],
)
def test_malformed_entry_points(target, message):
    with pytest.raises(PluginError, match=message):
        HandSpec(name="h", entry_point=target).load()


def test_specs_stay_hashable_with_settings():
    spec = SimSpec(name="s", entry_point="x:y", settings={"a": 1})
    assert hash(spec) == hash(SimSpec(name="s", entry_point="x:y", settings={"a": 2}))
