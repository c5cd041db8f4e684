"""ges_core.executors without Ray: the local executor (this process and a spawned pool), worker deaths, stopping
early, choosing by name and the command-line options. Ray's executor: tests/test_executor_ray.py."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

import pytest
from helpers_tasks import die_on_victim, fail_on_three, gone_within, process_gone, run_all, square_with_pid

import ges_core.cli as cli
from ges_core.errors import BackendUnavailable, ConfigError, UnknownNameError
from ges_core.executors import (
    LocalExecutor,
    TaskLostError,
    add_executor_options,
    executor_options,
    make_executor,
)


# -- task doubles (module level: a spawned worker imports them) ---------------------------------------------------
def slow_marked(i: int, marker_dir: str) -> int:
    (Path(marker_dir) / f"started-{i}").touch()
    time.sleep(0.3)
    return i


_SETUP_CALLS: list[int] = []


def record_setup(value: int) -> None:
    _SETUP_CALLS.append(value)
    os.environ["GES_TEST_SETUP"] = str(value)


def read_setup(_: int) -> str | None:
    return os.environ.get("GES_TEST_SETUP")


# -- this process -----------------------------------------------------------------------------------------------
def test_one_worker_runs_in_this_process_and_reports_a_failing_task():
    done = run_all(LocalExecutor(), fail_on_three, range(5))
    assert sorted(done) == [0, 1, 2, 3, 4]
    assert [done[i].result() for i in (0, 1, 2, 4)] == [0, 1, 2, 4]
    assert isinstance(done[3].error, ValueError) and not done[3].ok
    with pytest.raises(ValueError, match="task 3 fails on purpose"):
        done[3].result()


def test_setup_runs_in_this_process_before_the_tasks(monkeypatch):
    monkeypatch.delenv("GES_TEST_SETUP", raising=False)
    _SETUP_CALLS.clear()
    done = run_all(LocalExecutor(setup=record_setup, setup_args=(7,)), read_setup, range(2))
    assert _SETUP_CALLS == [7] and {d.value for d in done.values()} == {"7"}


# -- a spawned pool ------------------------------------------------------------------------------------------------
def test_pool_gives_the_same_values_from_other_processes():
    here = run_all(LocalExecutor(), square_with_pid, range(6))
    pool = run_all(LocalExecutor(workers=2), square_with_pid, range(6))
    assert {i: d.value[0] for i, d in here.items()} == {i: d.value[0] for i, d in pool.items()}
    assert {d.value[1] for d in here.values()} == {os.getpid()}
    assert os.getpid() not in {d.value[1] for d in pool.values()}


def test_pool_runs_setup_in_each_worker_and_reports_a_failing_task():
    done = run_all(LocalExecutor(workers=2, setup=record_setup, setup_args=(5,)), read_setup, range(3))
    assert {d.value for d in done.values()} == {"5"}
    failing = run_all(LocalExecutor(workers=2), fail_on_three, range(5))
    assert isinstance(failing[3].error, ValueError) and all(failing[i].ok for i in (0, 1, 2, 4))


def test_a_killed_pool_worker_loses_no_task(tmp_path):
    """The victim kills its worker on the first attempt: the broken pool is replaced and the lost calls rerun."""
    done = run_all(LocalExecutor(workers=2), die_on_victim, range(6), 2, str(tmp_path), 1)
    assert all(d.ok for d in done.values()), {i: d.error for i, d in done.items()}
    assert {i: d.value[0] for i, d in done.items()} == {i: i for i in range(6)}
    assert done[2].attempts == 2 and len(list(tmp_path.glob("attempt-*"))) == 2


def test_a_pool_that_breaks_between_a_result_and_the_next_submit_loses_no_task(monkeypatch):
    """A worker that dies after ``wait`` returned another call's result makes the pool's next ``submit`` raise
    BrokenProcessPool (seen once under load in the suite: the error escaped and ended the run). Forced here on the
    real pool's third submit: the refused call waits for the next pool and every call finishes, once each."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    submit, submits = ProcessPoolExecutor.submit, []

    def refuse_third(pool, *args, **kwargs):
        submits.append(1)
        if len(submits) == 3:
            raise BrokenProcessPool("a child process terminated abruptly (forced by the test)")
        return submit(pool, *args, **kwargs)

    monkeypatch.setattr(ProcessPoolExecutor, "submit", refuse_third)
    done = run_all(LocalExecutor(workers=2), square_with_pid, range(5))
    assert {i: d.value[0] for i, d in done.items()} == {i: i * i for i in range(5)}
    assert all(d.ok and d.attempts == 1 for d in done.values())  # the refused call never ran: not an attempt
    assert len(submits) == 6  # five calls and the refused submit


def test_a_task_that_always_kills_its_worker_is_reported_lost_and_the_others_finish(tmp_path):
    done = run_all(LocalExecutor(workers=2, max_retries=1), die_on_victim, range(6), 2, str(tmp_path), 99)
    # one death beside another call (no one charged), then two alone: the first attempt and max_retries=1
    assert isinstance(done[2].error, TaskLostError) and done[2].attempts == 3
    assert "died on each of 3 attempt(s)" in str(done[2].error) and "run the same command again" in str(done[2].error)
    others = [i for i in range(6) if i != 2]
    assert all(done[i].ok and done[i].value[0] == i for i in others)


POOL_PARENT = """
import sys
sys.path.insert(0, {tests!r})
from helpers_tasks import run_all, sleep_with_pid
from ges_core.executors import LocalExecutor

if __name__ == "__main__":
    run_all(LocalExecutor(workers=2), sleep_with_pid, range(2), {marks!r}, 600)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc are Linux's")
def test_pool_workers_die_with_a_killed_parent(tmp_path):
    """A SIGKILLed parent (a killed ``ges synth --workers 2``) leaves no pool worker running its task."""
    import subprocess

    marks = tmp_path / "marks"
    marks.mkdir()
    script = tmp_path / "parent.py"
    script.write_text(POOL_PARENT.format(tests=os.path.dirname(__file__), marks=str(marks)))
    parent = subprocess.Popen([sys.executable, str(script)])
    try:
        deadline = time.monotonic() + 120
        while len(list(marks.glob("pid-*"))) < 2 and time.monotonic() < deadline and parent.poll() is None:
            time.sleep(0.1)
        pids = [int(f.read_text()) for f in sorted(marks.glob("pid-*"))]
        assert len(pids) == 2 and not any(process_gone(p) for p in pids), pids  # both tasks run, in two workers
    finally:
        parent.kill()
        parent.wait()
    assert gone_within(pids, 10), pids


def test_stopping_early_starts_no_queued_task(tmp_path):
    with LocalExecutor(workers=2) as ex:
        for i in range(8):
            ex.submit(slow_marked, i, str(tmp_path))
        first = next(iter(ex.as_completed()))
    assert first.ok
    started = len(list(tmp_path.glob("started-*")))
    assert 1 <= started <= 4, f"{started} of 8 tasks started after the consumer stopped at the first result"


def test_submit_after_iterating_is_refused():
    ex = LocalExecutor()
    ex.submit(square_with_pid, 1)
    list(ex.as_completed())
    with pytest.raises(RuntimeError, match="submit every task before"):
        ex.submit(square_with_pid, 2)


# -- choosing an executor ---------------------------------------------------------------------------------------------
def test_make_executor_by_name_and_its_errors():
    assert isinstance(make_executor("local", workers=2), LocalExecutor)
    with pytest.raises(UnknownNameError, match="Did you mean 'ray'"):
        make_executor("rya")
    with pytest.raises(ConfigError, match="names a Ray cluster but the executor is 'local'; add --executor ray"):
        make_executor("local", address="ray://head:10001")
    with pytest.raises(ConfigError, match="workers must be a whole number >= 1, got 0"):
        make_executor("local", workers=0)


def test_missing_ray_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError, as where it is not installed
    with pytest.raises(BackendUnavailable, match=r"needs Ray.*pip install 'ges-unigrasp\[ray\]'"):
        make_executor("ray")


def test_a_ray_executor_with_nothing_to_do_starts_no_ray(monkeypatch):
    """A fully resumed run submits nothing: it must not start (or even import) Ray."""
    from ges_core.executors.ray_cluster import RayExecutor

    monkeypatch.setitem(sys.modules, "ray", None)  # importing Ray now would fail
    with RayExecutor(workers=2) as ex:
        assert list(ex.as_completed()) == []


def test_cli_options_and_address_without_ray_executor(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    add_executor_options(parser)
    assert executor_options(parser.parse_args([])) == {"executor": "local", "address": None}
    assert executor_options(parser.parse_args(["--executor", "ray", "--address", "auto"])) == {
        "executor": "ray",
        "address": "auto",
    }
    with pytest.raises(ConfigError, match="--address auto is the address of a Ray cluster: add --executor ray"):
        executor_options(parser.parse_args(["--address", "auto"]))
    out = tmp_path / "ds"
    argv = ["synth", "--hands", "allegro", "--objects", "procedural/cube/000", "--out", str(out), "--address", "auto"]
    assert cli.main(argv) == 1 and not out.exists()
    assert "add --executor ray" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["retarget", "ds", "--from", "shadow", "--to", "allegro", "--executor", "dask"])
    assert "invalid choice: 'dask'" in capsys.readouterr().err


# -- the synthesis pipeline's use -------------------------------------------------------------------------------------
def runner_killing_its_worker(task, context) -> list[tuple[int, str]]:
    """Test double of run_task: SIGKILLs its worker on the task of the object "victim", every time."""
    if any(oid == "victim" for oid, _ in task.pairs):
        os.kill(os.getpid(), signal.SIGKILL)
    return [(task.index, oid) for oid, _ in task.pairs]


@pytest.mark.slow  # 4 pools of spawned workers, each importing torch (set_torch_threads): ~10 s, a minute when loaded
def test_a_lost_synthesis_task_is_raised_after_every_other_tasks_records():
    """Through run_synthesis's task loop: the victim's worker dies on every attempt (no retry here: each retry
    costs a fresh pool whose workers import torch)."""
    from ges_core.synthesis.run import pipeline
    from ges_core.synthesis.run.tasks import plan_tasks

    tasks, _ = plan_tasks(["a", "b", "victim", "c"], ["allegro"], 1, lambda oid, hand: False)
    got = []
    with pytest.raises(TaskLostError) as lost:
        for records in pipeline._results(tasks, None, 2, runner=runner_killing_its_worker, max_retries=0):
            got += records
    assert sorted(got) == [(0, "a"), (1, "b"), (3, "c")]
    assert "1 of 4 synthesis tasks were lost" in str(lost.value)
    assert "objects not written: victim (allegro)" in str(lost.value) and "run the same command again" in str(
        lost.value
    )
