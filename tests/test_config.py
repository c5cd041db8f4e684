"""YAML config loading: overrides, unknown keys, every problem reported with its dotted path."""

from __future__ import annotations

import pytest
from pydantic import Field

from ges_core.config import (
    STORED_WHEN_SET,
    ConfigModel,
    RegistryConfig,
    absent_means,
    absent_paths,
    apply_overrides,
    fill_absent,
    load_config,
    stored_dump,
)
from ges_core.errors import ConfigError
from ges_core.sim import SceneConfig
from ges_core.sim_check import SimCheckConfig


def test_overrides_parse_yaml_values_and_nest():
    data = apply_overrides(
        {"scene": {"timestep": 0.01}}, ["scene.num_envs=4", "hand=allegro", "box_half_extents=[0.1,0.1,0.1]"]
    )
    cfg = SimCheckConfig.model_validate(data)
    assert cfg.scene.num_envs == 4 and cfg.scene.timestep == 0.01 and cfg.hand == "allegro"
    assert cfg.box_half_extents == (0.1, 0.1, 0.1)


def test_overrides_do_not_mutate_input():
    data = {"scene": {"timestep": 0.01}}
    apply_overrides(data, ["scene.timestep=0.02"])
    assert data == {"scene": {"timestep": 0.01}}


def test_every_problem_listed_with_path(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("scene:\n  timestep: -1\n  num_envs: 0\nclosure: 2\nbogus: 1\n")
    with pytest.raises(ConfigError) as err:
        load_config(SimCheckConfig, path)
    problems = err.value.problems
    assert any(p.startswith("scene.timestep") for p in problems)
    assert any(p.startswith("scene.num_envs") for p in problems)
    assert any(p.startswith("closure") for p in problems)
    assert any(p.startswith("bogus") and "Extra inputs" in p for p in problems)
    assert str(path) in str(err.value)


def test_a_problem_an_override_made_names_the_override_and_the_files_do_not(tmp_path):
    """The file's own bad value is listed as the file's; each bad -o item is named beside its problem, whether it
    set the failing key itself, a mapping holding it, or a key under a value that is not a mapping."""
    path = tmp_path / "c.yaml"
    path.write_text("closure: 2\n")
    overrides = ["scene.timestep=-1", "scene.typo=3", "box_half_extents=wide", "hand=allegro"]
    with pytest.raises(ConfigError) as err:
        load_config(SimCheckConfig, path, overrides)
    problems = {p.split(":")[0]: p for p in err.value.problems}
    assert not problems["closure"].endswith(")")  # the file's: no override named
    assert problems["scene.timestep"].endswith(" (set by -o scene.timestep=-1)")
    assert problems["scene.typo"].endswith(" (set by -o scene.typo=3)")
    assert problems["box_half_extents"].endswith(" (set by -o box_half_extents=wide)")
    assert not any("hand=allegro" in p for p in err.value.problems)  # a valid override is named nowhere
    with pytest.raises(ConfigError) as err:
        load_config(SimCheckConfig, None, ["scene={timestep: -1}"])  # a mapping set whole: its keys are its
    assert err.value.problems[0].startswith("scene.timestep: ")
    assert err.value.problems[0].endswith(" (set by -o scene={timestep: -1})")


@pytest.mark.parametrize(
    ("text", "message"),
    [("a: [1, 2\n", "not valid YAML"), ("- 1\n- 2\n", "must hold a mapping")],
)
def test_malformed_files(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(SceneConfig, path)


def test_missing_file():
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(SceneConfig, "/nonexistent/x.yaml")


def test_bad_override_syntax():
    with pytest.raises(ConfigError, match="must look like key.sub=value"):
        apply_overrides({}, ["timestep"])


def test_shipped_registry_yaml_validates():
    from conftest import REPO

    cfg = load_config(RegistryConfig, REPO / "registry.yaml")
    assert cfg.defaults.hand and cfg.defaults.sim


def _all_modules() -> list[str]:
    """Every module of ges_core and the built-in plugins (engines are imported lazily, so all import here)."""
    import pkgutil

    import ges_core
    import ges_plugins

    names = []
    for package in (ges_core, ges_plugins):
        names += [m.name for m in pkgutil.walk_packages(package.__path__, prefix=package.__name__ + ".")]
    return [n for n in names if not n.endswith("__main__")]


def test_every_settings_model_derives_from_config_model():
    import importlib

    from pydantic import BaseModel

    from ges_core.config import ConfigModel

    found: dict[str, type] = {}
    for name in _all_modules():
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, type) and issubclass(value, BaseModel) and value.__module__ == name:
                found[f"{name}.{value.__qualname__}"] = value
    plain = sorted(name for name, cls in found.items() if cls is not ConfigModel and not issubclass(cls, ConfigModel))
    assert len(found) > 20 and plain == []


def test_nan_and_inf_are_refused_in_every_nested_config():
    from ges_core.synthesis import SynthesisConfig

    for key in ("retarget.roll_deg", "contacts.force_closure.mu", "retarget.wrist_search.distinct_deg", "refine.gamma"):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.") + ": Input should be a finite number"):
            load_config(SynthesisConfig, overrides=[f"{key}=.nan"])
    with pytest.raises(ConfigError, match="timestep: Input should be a finite number"):
        load_config(SceneConfig, overrides=["timestep=.inf"])


def test_the_shipped_demo_config_equals_the_built_in_defaults():
    """An installed wheel has no configs/demo.yaml and runs on DemoConfig's defaults: they must not drift apart."""
    from pathlib import Path

    from ges_core.synthesis.run.demo import DemoConfig

    shipped = Path(__file__).resolve().parents[1] / "configs" / "demo.yaml"
    assert load_config(DemoConfig, shipped) == DemoConfig()


class _Inner(ConfigModel):
    kept: int = 1
    late: int = Field(0, json_schema_extra=STORED_WHEN_SET)


class _Outer(ConfigModel):
    inner: _Inner = Field(default_factory=_Inner)
    extras: dict[str, int] = Field(default_factory=dict, json_schema_extra=STORED_WHEN_SET)
    named: float = Field(2.0, alias="renamed")
    by_name: dict[str, _Inner] = Field(default_factory=dict)


def test_stored_dump_leaves_out_late_fields_at_their_defaults_at_any_depth():
    """A field added after configs were stored is absent while at its default (the stored JSON and its hash as
    before), present once set; every other field, defaults included, is stored as model_dump gives it."""
    assert stored_dump(_Outer()) == {"inner": {"kept": 1}, "renamed": 2.0, "by_name": {}}
    changed = _Outer.model_validate({"inner": {"late": 3}, "extras": {"a": 1}})
    assert stored_dump(changed) == {"inner": {"kept": 1, "late": 3}, "extras": {"a": 1}, "renamed": 2.0, "by_name": {}}
    # models keyed by name (LibraryConfig.object_properties): their late fields too
    named = _Outer.model_validate({"by_name": {"x": {}, "y": {"late": 4}}})
    assert stored_dump(named)["by_name"] == {"x": {"kept": 1}, "y": {"kept": 1, "late": 4}}
    assert _Outer.model_validate(stored_dump(_Outer())) == _Outer()  # what is left out reads back as the default


class _Changed(ConfigModel):
    kept: int = 1
    cap: float | None = Field(0.005, json_schema_extra=absent_means(None))


class _HoldsChanged(ConfigModel):
    inner: _Changed = Field(default_factory=_Changed)
    other: _Inner = Field(default_factory=_Inner)


def test_a_field_whose_default_changed_behaviour_is_stored_unless_it_asks_for_the_old_behaviour():
    """absent_means(None): the new default is stored (an old config, which lacks it, no longer matches a default run),
    the old behaviour is left out (it matches, and resumes), and a stored config that lacks it reads as the old
    behaviour, not as the new default, at any depth."""
    old_stored = {"inner": {"kept": 1}, "other": {"kept": 1}}  # written before the field existed
    assert stored_dump(_HoldsChanged()) == {"inner": {"kept": 1, "cap": 0.005}, "other": {"kept": 1}}
    assert stored_dump(_HoldsChanged.model_validate({"inner": {"cap": None}})) == old_stored
    assert stored_dump(_HoldsChanged.model_validate({"inner": {"cap": 0.01}}))["inner"]["cap"] == 0.01
    read = _HoldsChanged.model_validate(fill_absent(_HoldsChanged, old_stored))
    assert read.inner.cap is None and _HoldsChanged.model_validate(old_stored).inner.cap == 0.005
    assert fill_absent(_HoldsChanged, {}) == {"inner": {"cap": None}}  # a section stored without it: the same
    assert fill_absent(_HoldsChanged, {"inner": {"cap": 0.01}}) == {"inner": {"cap": 0.01}}  # stored: kept
    assert old_stored == {"inner": {"kept": 1}, "other": {"kept": 1}}  # the input is not changed
    assert absent_paths(_HoldsChanged) == {"inner.cap": None}  # what the dataset writer names on a refused resume
