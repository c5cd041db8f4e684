"""Issue 10, point 6: counts and names. Each probe of the issue, run through the ``ges`` command line in process.

A bad count on the command line is argparse's usage error (exit 2, one ``ges CMD: error: argument ...`` line);
everything else is one ``ges: error:`` line (exit 1). No probe starts a synthesis run: where an old bug would
have started one, ``run_synthesis`` / ``run_demo`` are replaced by a stub that fails the test.
"""

from __future__ import annotations

import argparse
import re

import pytest

import ges_core.synthesis as synthesis
import ges_core.synthesis.run.demo as demo
from ges_core.cli import build_parser, main
from ges_core.dataset import DatasetWriter
from ges_core.errors import ConfigError, PluginError, UnknownNameError
from ges_core.registry import load_registry
from ges_core.synthesis import SynthesisConfig

ONE = ["--objects", "procedural/can/000", "--hands", "allegro", "--no-progress"]
"""The smallest ``ges synth`` selection."""


def run(capsys, *argv: str) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``ges ARGV`` (argparse's exit 2 caught)."""
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def no_run(monkeypatch):
    """Stage 1 must not start: a call of run_synthesis or run_demo fails the test."""

    def refuse(*args, **kwargs):
        raise AssertionError("a synthesis run started")

    monkeypatch.setattr(synthesis, "run_synthesis", refuse)
    monkeypatch.setattr(demo, "run_demo", refuse)


def _usage_error(err: str, option: str, value: str) -> bool:
    """argparse's one error line (after its usage lines) names the option and the value."""
    last = err.strip().splitlines()[-1]
    return last.startswith("ges ") and f"argument {option}: " in last and repr(value) in last


# -- counts on the command line ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv, option, value",
    [
        (["synth", "--out", "X", "--limit", "0", *ONE], "--limit", "0"),  # started the whole library (1149)
        (["synth", "--out", "X", "--limit", "-1", *ONE], "--limit", "-1"),  # ran all but one
        (["synth", "--out", "X", "--limit", "two", *ONE], "--limit", "two"),
        (["synth", "--out", "X", "--workers", "0", *ONE], "--workers", "0"),  # ran one worker
        (["synth", "--out", "X", "--workers", "-3", *ONE], "--workers", "-3"),
        (["demo", "--out", "X", "--workers", "0"], "--workers", "0"),  # ran the config's workers
        (["retarget", "X", "--from", "allegro", "--to", "shadow", "--workers", "0"], "--workers", "0"),
        (["env", "baseline", "X", "--envs", "0"], "--envs", "0"),
        (["env", "baseline", "X", "--envs", "1.5"], "--envs", "1.5"),
    ],
)
def test_a_bad_count_is_a_usage_error(capsys, tmp_path, no_run, argv, option, value):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert _usage_error(err, option, value), err
    assert "a whole number >= 1" in err
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize("objects", ["-2", "0", "21", "[]", "true"])
def test_demo_objects_out_of_range(capsys, tmp_path, no_run, objects):
    """``-o objects=-2`` ran 18 objects (all but the last two)."""
    code, _, err = run(capsys, "demo", "--out", str(tmp_path / "d"), "-o", f"objects={objects}")
    assert code == 1 and err.count("\n") == 1, err
    assert err.startswith("ges: error: invalid ") and "objects:" in err and "from 1 to 20" in err
    assert not (tmp_path / "d").exists()


def test_demo_objects_in_range_still_work():
    assert demo.DemoConfig(objects=3).object_ids() == list(demo.DEMO_OBJECTS[:3])
    assert demo.DemoConfig(objects=["procedural/box/000"]).object_ids() == ["procedural/box/000"]
    assert len(demo.DemoConfig().object_ids()) == len(demo.DEMO_OBJECTS)


# -- unknown plugin names: refused before the dataset folder exists ------------------------------------------


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--sim", "nosuch"], "unknown sim 'nosuch' (refine_sim)"),
        (["--sim", "sapein"], "Did you mean 'sapien'?"),
        (["--hands", "nosuch"], "unknown hand 'nosuch'"),
        (["--hands", "allegro", "shadwo"], "Did you mean 'shadow'?"),
        (["-o", "refine_sim=nosuch"], "unknown sim 'nosuch' (refine_sim)"),
        (["-o", "validate_sims=[nosuch]"], "unknown sim 'nosuch' (validate_sims)"),
    ],
)
def test_unknown_plugin_name_writes_nothing(capsys, tmp_path, extra, message):
    out = tmp_path / "ds"
    code, _, err = run(capsys, "synth", "--out", str(out), *ONE, *extra)
    assert code == 1 and err.count("\n") == 1 and message in err, err
    assert not out.exists()  # no manifest naming the unknown plugin: the corrected run is not refused


def test_unknown_name_through_the_library_writes_nothing(tmp_path):
    config = SynthesisConfig(validate_sims=("sapien", "pybulet"))
    with pytest.raises(UnknownNameError, match=r"unknown sim 'pybulet' \(validate_sims\)\. Did you mean 'pybullet'"):
        synthesis.run_synthesis(["procedural/can/000"], ["allegro"], config, tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_changed_config_advice_names_only_what_the_cli_has(capsys, tmp_path):
    """The refusal advised ``allow_config_change``, which no ``ges`` option sets."""
    out = tmp_path / "ds"
    with DatasetWriter(out, SynthesisConfig(attempts=1).dump()):
        pass
    code, _, err = run(capsys, "synth", "--out", str(out), *ONE, "-o", "validate_sims=[]")
    assert code == 1 and err.count("\n") == 1 and f"attempts: 1 -> {SynthesisConfig().attempts}" in err, err
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", err))  # every option the advice names is a real one
    assert {"--out", "--fresh"} <= named <= _options_of("synth") | _options_of("demo"), named
    assert "ges demo --fresh" in err and "--fresh" in _options_of("demo")
    python_only = "in Python, DatasetWriter(..., allow_config_change=True)"
    assert err.count("allow_config_change") == err.count(python_only) == 1, err  # named as Python, never as ges


def _options_of(command: str) -> set[str]:
    """The option strings of ``ges COMMAND``, from the parser itself."""
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return {option for action in sub.choices[command]._actions for option in action.option_strings}


# -- registry.yaml: defaults and settings --------------------------------------------------------------------


def test_unknown_default_hand_fails_ges_list(capsys, write_registry, monkeypatch):
    monkeypatch.setenv("GES_DISABLE_PLUGIN_AUTOLOAD", "1")  # the known hands are the built-ins, whatever is installed
    path = write_registry("defaults: {hand: nosuchhand}\n")
    code, out, err = run(capsys, "--registry", str(path), "list")
    assert code == 1 and "allegro" in out and "pybullet" in out  # still lists
    assert err == (
        "ges: error: unknown hand 'nosuchhand' in registry.yaml defaults.hand. Known hands: allegro, shadow.\n"
    )


def test_unknown_default_of_an_unlisted_kind_is_not_reported(capsys, write_registry):
    path = write_registry("defaults: {sim: nosuch}\n")
    assert run(capsys, "--registry", str(path), "list", "hand")[0] == 0
    assert run(capsys, "--registry", str(path), "list")[0] == 1


def test_building_the_default_names_the_misspelt_default(write_registry):
    registry = load_registry(write_registry("defaults: {hand: shadwo}\n"), autoload=False)
    with pytest.raises(UnknownNameError) as err:
        registry.build_hand()
    assert str(err.value) == (
        "unknown hand 'shadwo' in registry.yaml defaults.hand. Did you mean 'shadow'? Known hands: allegro, shadow."
    )


def test_unknown_default_in_a_command(capsys):
    code, _, err = run(capsys, "--set", "defaults.sim=sapein", "sim", "check", "--hand", "allegro")
    assert code == 1 and err.count("\n") == 1
    assert "unknown sim 'sapein' in registry.yaml defaults.sim. Did you mean 'sapien'?" in err


@pytest.mark.parametrize(
    "sim, setting, value, expected",
    [
        ("sapien", "contact_offset", '"x"', "float | None"),  # was: '<' not supported between 'float' and 'str'
        ("sapien", "contact_offset", "[0.1]", "float | None"),
        ("pybullet", "solver_iterations", "many", "int | None"),
        ("pybullet", "solver_iterations", "2.5", "int | None"),
    ],
)
def test_wrong_typed_setting_is_one_line(write_registry, sim, setting, value, expected):
    path = write_registry(f"settings: {{sim: {{{sim}: {{{setting}: {value}}}}}}}\n")
    with pytest.raises(ConfigError) as err:
        load_registry(path, autoload=False).build_sim(sim)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"sim '{sim}': setting {setting}=")
    assert f"is not {expected} (" in msg and f"settings.sim.{sim}.{setting}" in msg


def test_wrong_typed_setting_on_the_command_line(capsys):
    argv = ["--set", "settings.sim.sapien.contact_offset=x", "sim", "check", "--hand", "allegro", "--sim", "sapien"]
    code, _, err = run(capsys, *argv)
    assert code == 1 and err.count("\n") == 1
    assert "sim 'sapien': setting contact_offset='x' is not float | None (" in err and "not supported" not in err


FACTORY = """
from typing import Annotated
from pydantic import Field

CALLS = []

def typed(*, width: Annotated[float, Field(gt=0)] = 1.0, fingers: tuple[str, ...] = (), name: str = "h", **rest):
    CALLS.append((width, fingers, name, rest))
    return (width, fingers, name, rest)
"""

PLUGIN = """
from ges_core import hookimpl
from ges_core.specs import HandSpec

@hookimpl
def ges_register_hands(register):
    register(HandSpec(name="typed", entry_point="faults_factories:typed"))
"""


@pytest.fixture
def typed_registry(tmp_path, write_registry, monkeypatch):
    """A registry holding hand 'typed', whose factory annotates its settings; extra registry.yaml text."""
    import sys

    (tmp_path / "faults_factories.py").write_text(FACTORY)
    (tmp_path / "faults_hands.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield lambda extra: load_registry(write_registry("plugins: [faults_hands.py]\n" + extra), autoload=False)
    sys.modules.pop("faults_factories", None)


def test_every_plugin_gets_its_settings_checked_against_its_annotations(typed_registry):
    with pytest.raises(ConfigError, match=r"setting width=-1\.0 is not float \(Input should be greater than 0\)"):
        typed_registry("settings: {hand: {typed: {width: -1.0}}}\n").build_hand("typed")
    with pytest.raises(ConfigError, match=r"setting name=\[1\] is not str"):
        typed_registry("settings: {hand: {typed: {name: [1]}}}\n").build_hand("typed")


def test_settings_reach_the_factory_as_annotated(typed_registry):
    """YAML has lists, not tuples: a setting arrives converted as a config model field would be."""
    registry = typed_registry("settings: {hand: {typed: {fingers: [a, b], width: 2, other: x}}}\n")
    with pytest.raises(PluginError, match=r"returned tuple, not a HandModel"):  # it built, with a tuple
        registry.build_hand("typed")
    import faults_factories

    ((width, fingers, name, rest),) = faults_factories.CALLS  # what the factory received
    assert (width, type(width), fingers, name) == (2.0, float, ("a", "b"), "h")  # as its annotations say
    assert rest == {"other": "x"}  # **rest: passed on unchecked
