"""YAML config loading: overrides, unknown keys, every problem reported with its dotted path."""

from __future__ import annotations

import pytest

from ges_core.config import RegistryConfig, apply_overrides, load_config
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
