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


ENGINE_PLUGIN = """
from ges_core import hookimpl
from ges_core.specs import SimSpec

@hookimpl
def ges_register_sims(register):
    register(SimSpec(name="fancy", entry_point="x:y", requires=("no_such_engine_xyz",), install="pip install 'x[f]'"))
    register(SimSpec(name="plain", entry_point="x:y", requires=("no_such_engine_xyz",)))
"""


def test_list_says_what_to_install_for_a_missing_engine(capsys, tmp_path):
    (tmp_path / "engines.py").write_text(ENGINE_PLUGIN)
    (tmp_path / "registry.yaml").write_text("plugins: [engines.py]\n")
    code, out, _ = run(capsys, "--registry", str(tmp_path / "registry.yaml"), "list", "sim")
    lines = {line.split()[0].lstrip("*"): line for line in out.splitlines()[1:]}
    assert code == 0 and lines["fancy"].endswith("[needs: pip install 'x[f]']")
    assert lines["plain"].endswith("[missing: no_such_engine_xyz]") and "needs" not in lines["sapien"]


def test_info_shows_requirements_and_settings(capsys):
    code, out, _ = run(capsys, "--set", "settings.sim.sapien.contact_offset=0.004", "info", "sim", "sapien")
    assert code == 0 and "requires: sapien (installed)" in out and "settings: contact_offset=0.004" in out


@pytest.mark.parametrize(
    "setting, says",
    [
        ("solver_iterations=abc", "setting solver_iterations='abc' is not int | None"),
        ("friction_anchors=3", "setting friction_anchors=3 is not bool | Literal['on_touch']"),
        ("bogus=1", "unexpected keyword argument 'bogus'"),
    ],
)
def test_info_refuses_a_bad_set_value_as_building_would(capsys, setting, says):
    """`ges info` checks the settings against the factory (it used to print a bad --set value as if fine)."""
    code, out, err = run(capsys, "--set", f"settings.sim.pybullet.{setting}", "info", "sim", "pybullet")
    assert code == 1 and says in err and "settings.sim.pybullet" in err and "settings:" not in out


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


def _user_objects(tmp_path, name: str, vertices, faces):
    import numpy as np
    import trimesh

    folder = tmp_path / "objects" / "junk"
    folder.mkdir(parents=True)
    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False)
    (folder / f"{name}.obj").write_text(mesh.export(file_type="obj"))
    return tmp_path / "objects"


def test_mesh_with_nan_vertices(capsys, tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    vertices = box.vertices.copy()
    vertices[0, 0] = float("nan")
    folder = _user_objects(tmp_path, "nan_box", vertices, box.faces)
    code, _, err = run(capsys, "sim", "check", "--object", "user/junk/nan_box", "--user-dir", str(folder))
    assert code == 1 and "nan_box" in err and "NaN" in err and err.count("\n") == 1


def test_mesh_with_no_volume(capsys, tmp_path):
    folder = _user_objects(
        tmp_path, "sheet", [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]], [[0, 1, 2], [1, 3, 2]]
    )
    code, _, err = run(capsys, "sim", "check", "--object", "user/junk/sheet", "--user-dir", str(folder))
    assert code == 1 and "sheet" in err and err.count("\n") == 1


def test_missing_mesh_file_in_library(capsys, tmp_path):
    code, _, err = run(capsys, "sim", "check", "--object", "user/junk/ghost", "--user-dir", str(tmp_path))
    assert code == 1 and "ghost" in err


def test_object_larger_than_the_hand_can_span(capsys):
    code, out, err = run(
        capsys, "sim", "check", "--hand", "allegro", "--sim", "pybullet", "-o", "box_half_extents=[0.3,0.3,0.3]"
    )
    assert code == 1 and out == ""
    assert "60.0 cm across at its narrowest" in err and "hand 'allegro' opens at most" in err


def test_missing_hand_asset(capsys, tmp_path):
    (tmp_path / "registry.yaml").write_text(f"settings:\n  hand:\n    shadow: {{asset_dir: {tmp_path / 'nowhere'}}}\n")
    code, _, err = run(capsys, "--registry", str(tmp_path / "registry.yaml"), "info", "hand", "shadow")
    assert code == 1 and "nowhere" in err and "gymnasium-robotics" in err and err.count("\n") == 1


def test_broken_hand_urdf(capsys, tmp_path):
    from conftest import EXAMPLE_HAND_PKG

    (tmp_path / "hand.yaml").write_text((EXAMPLE_HAND_PKG / "ges_example_hand" / "gripper.yaml").read_text())
    (tmp_path / "hand.urdf").write_text("<robot name='x'><link name='palm'>")
    code, _, err = run(capsys, "hand", "lint", str(tmp_path / "hand.yaml"))
    assert code == 1 and "URDF is not valid XML" in err


def _options(parser, path=()):
    """(command path, option, action) of every option of every sub-command."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, (*path, name))
        elif action.option_strings:
            yield path, action.option_strings[-1], action


def test_every_numeric_option_is_checked_in_one_place():
    """A bare ``type=int`` takes 0 and negatives silently (``--limit 0`` started the whole library)."""
    from ges_core.cli import args, build_parser

    bare = [
        f"ges {' '.join(path)} {option}"
        for path, option, action in _options(build_parser())
        if action.type in (int, float)
    ]
    assert bare == [], f"use a type from ges_core.cli.args: {bare}"
    checked = {(path, option): action.type for path, option, action in _options(build_parser())}
    assert checked[("synth",), "--limit"] is checked[("env", "baseline"), "--envs"] is args.positive_int


@pytest.mark.parametrize(
    "check, text, value",
    [("positive_int", "3", 3), ("non_negative_int", "0", 0), ("positive_float", "0.001", 0.001)],
)
def test_count_types_take_good_values(check, text, value):
    from ges_core.cli import args

    assert getattr(args, check)(text) == value


@pytest.mark.parametrize(
    "check, text",
    [("positive_int", "0"), ("positive_int", "1e3"), ("non_negative_int", "-1"), ("positive_float", "nan"),
     ("positive_float", "inf"), ("positive_float", "0"), ("positive_float", "x")],
)  # fmt: skip
def test_count_types_refuse_bad_values(check, text):
    import argparse

    from ges_core.cli import args

    with pytest.raises(argparse.ArgumentTypeError, match=rf"^'{text}' is not a"):
        getattr(args, check)(text)


def test_a_closed_output_pipe_ends_quietly():
    """``ges list | head -1``: the reader closing the pipe is no error of ours (no line, no traceback)."""
    import subprocess
    import sys

    script = "import sys; from ges_core.cli import main; sys.exit(main(['list']))"
    ges = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    ges.stdout.close()  # the reader goes away before ges writes
    err = ges.stderr.read().decode()
    assert ges.wait(timeout=60) == 141 and "error" not in err and "Traceback" not in err
