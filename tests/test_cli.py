"""The ``ges`` command line: listing, info, and one clear line for every kind of bad input."""

from __future__ import annotations

import pytest

from ges_core.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_shows_builtins_with_sources(capsys):
    code, out, _ = run(capsys, "list")
    assert code == 0
    for name in ("shadow", "allegro", "sapien", "pybullet"):
        assert name in out
    assert "ges-unigrasp" in out and "*shadow" in out.replace(" ", "")


def test_unknown_hand_is_one_line_with_known_names(capsys):
    code, out, err = run(capsys, "info", "hand", "shadwo")
    assert code == 1 and out == ""
    assert err.count("\n") == 1
    assert "unknown hand 'shadwo'" in err and "Did you mean 'shadow'" in err and "allegro" in err


def test_unknown_sim_fails_before_simulating(capsys):
    code, _, err = run(capsys, "sim", "check", "--hand", "allegro", "--sim", "mujoco_xla")
    assert code == 1 and "unknown sim 'mujoco_xla'" in err and "pybullet" in err


def test_bad_config_value_names_the_path(capsys):
    code, _, err = run(capsys, "sim", "check", "-o", "scene.timestep=-1")
    assert code == 1 and "scene.timestep" in err and err.count("\n") == 1


def test_plugin_raising_on_import(capsys, tmp_path):
    (tmp_path / "bad.py").write_text("import does_not_exist_anywhere\n")
    (tmp_path / "registry.yaml").write_text("plugins: [bad.py]\n")
    code, _, err = run(capsys, "--registry", str(tmp_path / "registry.yaml"), "list")
    assert code == 1
    assert "local plugin 'bad.py'" in err and "does_not_exist_anywhere" in err and "Traceback" not in err


def test_debug_shows_the_traceback(tmp_path):
    (tmp_path / "bad.py").write_text("raise ValueError('kaputt')\n")
    (tmp_path / "registry.yaml").write_text("plugins: [bad.py]\n")
    from ges_core.errors import PluginError

    with pytest.raises(PluginError) as err:
        main(["--debug", "--registry", str(tmp_path / "registry.yaml"), "list"])
    assert isinstance(err.value.__cause__, ValueError)


def test_missing_registry_file(capsys, tmp_path):
    code, _, err = run(capsys, "--registry", str(tmp_path / "nope.yaml"), "list")
    assert code == 1 and "cannot read config file" in err


def test_registry_settings_reach_the_factory(capsys, tmp_path):
    (tmp_path / "registry.yaml").write_text("settings:\n  hand:\n    allegro: {bogus_option: 1}\n")
    code, _, err = run(capsys, "--registry", str(tmp_path / "registry.yaml"), "info", "hand", "allegro")
    assert code == 1 and "allegro" in err and "bogus_option" in err
