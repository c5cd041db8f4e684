"""Torch threads per process (ges_core.threads): where the count comes from, the CLI and the worker processes."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from ges_core import threads
from ges_core.cli import main
from ges_core.errors import ConfigError
from ges_core.synthesis.run import pipeline


@pytest.fixture(autouse=True)
def _restore_torch_threads():
    """Each test starts without $GES_THREADS; the process's count and variable are restored after it (the CLI
    sets the variable itself, outside monkeypatch)."""
    before, env = torch.get_num_threads(), os.environ.pop(threads.ENV_VAR, None)
    yield
    torch.set_num_threads(before)
    os.environ.pop(threads.ENV_VAR, None)
    if env is not None:
        os.environ[threads.ENV_VAR] = env


def test_the_count_comes_from_the_request_then_the_environment_then_the_default(monkeypatch):
    assert threads.resolve_threads() == threads.DEFAULT_THREADS == 1
    monkeypatch.setenv(threads.ENV_VAR, " 3 ")
    assert threads.resolve_threads() == 3
    assert threads.resolve_threads(2) == 2


@pytest.mark.parametrize("raw", ["two", "1.5"])
def test_a_malformed_environment_value_names_the_variable(monkeypatch, raw):
    monkeypatch.setenv(threads.ENV_VAR, raw)
    with pytest.raises(ConfigError, match=rf"^GES_THREADS='{raw}' is not a whole number; set it to"):
        threads.resolve_threads()


@pytest.mark.parametrize("bad", [0, -2, True])
def test_a_count_below_one_is_refused(monkeypatch, bad):
    with pytest.raises(ConfigError, match=r"must be a whole number >= 1 \(torch threads per process\)"):
        threads.resolve_threads(bad)
    monkeypatch.setenv(threads.ENV_VAR, "0")
    with pytest.raises(ConfigError, match=r"^GES_THREADS must be a whole number >= 1"):
        threads.resolve_threads()


def test_set_torch_threads_changes_this_process():
    other = 2 if torch.get_num_threads() == 1 else 1
    assert threads.set_torch_threads(other) == other
    assert torch.get_num_threads() == other


def test_configure_exports_the_count_and_applies_it_once_torch_is_loaded(monkeypatch):
    torch.set_num_threads(2)
    assert threads.configure_threads() == 1
    assert torch.get_num_threads() == 1
    assert os.environ[threads.ENV_VAR] == "1"


def test_the_cli_sets_the_count_before_the_command_runs(monkeypatch, capsys):
    torch.set_num_threads(1)
    assert main(["--threads", "2", "list"]) == 0
    assert torch.get_num_threads() == 2
    assert main(["list"]) == 0  # an explicit count is exported, so the next command without one keeps it
    assert torch.get_num_threads() == 2
    monkeypatch.setenv(threads.ENV_VAR, "zero")
    assert main(["list"]) == 1
    assert "ges: error: GES_THREADS='zero' is not a whole number" in capsys.readouterr().err


@dataclass(frozen=True)
class _Task:
    index: int


def report_threads(task, context) -> list[tuple[int, int]]:
    """Test double of run_task (module level: a spawned worker imports it): [(task index, torch threads)]."""
    return [(task.index, torch.get_num_threads())]


def test_each_spawned_worker_runs_with_one_thread_by_default():
    """The pool's initializer sets the count in every worker (an explicit count takes the same path: see the
    in-process test below)."""
    torch.set_num_threads(3)  # the parent's own count must not reach the workers (spawn: torch starts afresh)
    tasks = [_Task(0), _Task(1)]
    got = [r for records in pipeline._results(tasks, None, 2, runner=report_threads) for r in records]
    assert sorted(got) == [(0, 1), (1, 1)]


@pytest.mark.parametrize("asked", [None, 2])
def test_a_run_in_this_process_sets_its_count(asked):
    torch.set_num_threads(3)
    got = list(pipeline._results([_Task(0)], None, 1, runner=report_threads, threads=asked))
    assert got == [[(0, asked or 1)]]


def test_the_cli_refuses_a_count_below_one(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--threads", "0", "list"])
    assert exit_.value.code == 2
    assert "argument --threads: '0' is not a whole number >= 1" in capsys.readouterr().err


def test_the_thread_count_does_not_change_retargeting():
    """Why SynthesisConfig.threads stays out of the run_config hash: the same grasps with 1 and 2 threads."""
    from ges_core.objects.library import ObjectLibrary
    from ges_core.registry import load_registry
    from ges_core.synthesis.contacts.generate import generate_contacts
    from ges_core.synthesis.retarget.retargeter import GraspRetargeter
    from ges_core.synthesis.retarget.search import ObjectCloud

    library = ObjectLibrary(sources=("procedural",), procedural_count=1)
    contacts, clouds = [], []
    for object_id in ("procedural/box/000", "procedural/can/000"):
        points, normals = library.point_cloud(object_id, 512, seed=0)
        contacts.append(generate_contacts(points, normals).contacts)
        clouds.append(ObjectCloud(points, normals))
    retargeter = GraspRetargeter(load_registry().build_hand("shadow"))
    grasps = {}
    for count in (1, 2):
        torch.set_num_threads(count)
        grasps[count] = retargeter.retarget_ranked(contacts, clouds, keep=2)
    for one, two in zip(grasps[1], grasps[2], strict=True):
        assert len(one) == len(two) == 2
        for a, b in zip(one, two, strict=True):
            assert np.array_equal(a.q, b.q) and np.array_equal(a.wrist_pose, b.wrist_pose)
