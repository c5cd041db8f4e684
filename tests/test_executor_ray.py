"""The Ray executor against a real local Ray instance (one per module, started and stopped here): the same
values and records as a local run, a worker killed mid-run, a Ray run killed and resumed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed: pip install 'ges-unigrasp[ray]'")

import helpers_tasks  # noqa: E402
from helpers_tasks import die_on_victim, fail_on_three, run_all, square_with_pid  # noqa: E402

from ges_core.config import load_config  # noqa: E402
from ges_core.dataset import open_dataset, validate_dataset  # noqa: E402
from ges_core.executors import TaskLostError, make_executor  # noqa: E402
from ges_core.executors.ray_cluster import OBJECT_STORE_BYTES  # noqa: E402
from ges_core.synthesis import SynthesisConfig, run_synthesis  # noqa: E402

OBJECTS = ["procedural/cube/000", "procedural/box/000", "procedural/can/000"]
FAST = {"validate.hold_steps": "60", "robust.enabled": "false", "chunk_size": "1"}
"""Short validation, no perturbation trials, one object per task (so a kill falls between tasks)."""


@pytest.fixture(scope="module")
def cluster() -> str:
    """A Ray instance of 2 CPUs for this module (about 5 s to start); its address, for a second driver."""
    # the task doubles are pickled by value: a Ray worker cannot import a test helper module by name
    ray.cloudpickle.register_pickle_by_value(helpers_tasks)
    context = ray.init(num_cpus=2, object_store_memory=OBJECT_STORE_BYTES, include_dashboard=False, log_to_driver=False)
    yield context.address_info["address"]
    ray.shutdown()


# -- the executor ---------------------------------------------------------------------------------------------------
def test_ray_gives_the_local_values_and_each_tasks_own_error(cluster):
    local = run_all(make_executor("local"), square_with_pid, range(6))
    remote = run_all(make_executor("ray"), square_with_pid, range(6))
    assert {i: d.value[0] for i, d in remote.items()} == {i: d.value[0] for i, d in local.items()}
    assert os.getpid() not in {d.value[1] for d in remote.values()}  # they ran in Ray's workers
    failing = run_all(make_executor("ray"), fail_on_three, range(5))
    assert type(failing[3].error) is ValueError and "task 3 fails on purpose" in str(failing[3].error)
    assert all(failing[i].ok for i in (0, 1, 2, 4))
    assert ray.is_initialized()  # an executor leaves a Ray it did not start running


def test_a_killed_ray_worker_loses_only_its_task(cluster, tmp_path):
    """The victim SIGKILLs its worker on the first attempt: Ray runs it again, every other task is kept."""
    done = run_all(make_executor("ray"), die_on_victim, range(6), 2, str(tmp_path), 1)
    assert all(d.ok for d in done.values()), {i: d.error for i, d in done.items()}
    assert {i: d.value[0] for i, d in done.items()} == {i: i for i in range(6)}
    assert len(list(tmp_path.glob("attempt-*"))) == 2  # the victim ran twice: killed, then retried


def test_a_task_that_kills_every_worker_is_lost_and_the_rest_finish(cluster, tmp_path):
    done = run_all(make_executor("ray", max_retries=1), die_on_victim, range(6), 2, str(tmp_path), 99)
    assert isinstance(done[2].error, TaskLostError)
    assert "died on each of 2 attempt(s) (WorkerCrashedError)" in str(done[2].error)
    assert len(list(tmp_path.glob("attempt-*"))) == 2
    assert all(done[i].ok and done[i].value[0] == i for i in range(6) if i != 2)


# -- Stage 1 on Ray -------------------------------------------------------------------------------------------------
def _config() -> SynthesisConfig:
    """:data:`FAST` over the defaults (the settings of ``_killed_ray_run``'s command line)."""
    return load_config(SynthesisConfig, None, [f"{k}={v}" for k, v in FAST.items()])


def _record_bytes(root: Path) -> dict[str, bytes]:
    """Each record file's bytes by its path in the dataset (times live apart, in *.timing.json)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted((root / "records").rglob("*.npz"))}


def _killed_rayrun_all(out: Path, address: str, log: Path) -> None:
    """``ges synth --executor ray --address`` in another process, SIGKILLed once its first record is written.
    Its output goes to ``log`` (a pipe nobody reads while waiting could fill up and stall the run)."""
    argv = [sys.executable, "-m", "ges_core.cli", "synth", "--hands", "allegro", "--objects", *OBJECTS]
    argv += ["--sim", "sapien", "--out", str(out), *(a for k, v in FAST.items() for a in ("-o", f"{k}={v}"))]
    argv += ["--no-progress", "--executor", "ray", "--address", address]
    with log.open("w") as sink:
        proc = subprocess.Popen(argv, stdout=sink, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 600  # ~10 s normally; minutes on 2 cores at load 18 (full suite, -n 2)
        while not list(out.glob("records/*/*.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, f"the run ended by itself before the kill:\n{log.read_text()}"
    assert list(out.glob("records/*/*.npz")), f"no record written within 600 s; the run said:\n{log.read_text()}"


@pytest.mark.sim
def test_ray_records_equal_the_local_ones_byte_for_byte_and_a_killed_ray_run_resumes(cluster, tmp_path):
    config = _config()
    local = run_synthesis(OBJECTS, ["allegro"], config, tmp_path / "local")
    _killed_rayrun_all(tmp_path / "ray", cluster, tmp_path / "killed_run.log")
    kept = set(_record_bytes(tmp_path / "ray"))
    assert 1 <= len(kept) < len(OBJECTS)
    resumed = run_synthesis(OBJECTS, ["allegro"], config, tmp_path / "ray", executor="ray", workers=2)
    assert len(resumed.skipped) == len(kept) and len(resumed.skipped) + len(resumed.written) == len(OBJECTS)
    assert validate_dataset(tmp_path / "ray") == []
    assert sorted(local.written) == sorted(r.key for r in open_dataset(tmp_path / "ray"))
    assert _record_bytes(tmp_path / "ray") == _record_bytes(tmp_path / "local")  # same files, same bytes


@pytest.mark.sim
def test_demo_and_retarget_run_on_ray(cluster, tmp_path, capsys):
    """The CLI path on a running cluster (``--address``): the demo (its pictures drawn by the Ray workers), then
    ``ges retarget``, whose workers read the source dataset's contacts."""
    import numpy as np

    import ges_core.cli as cli

    ray_args = ["--executor", "ray", "--address", cluster, "--no-progress"]
    fast = ["-o", "synthesis.validate.hold_steps=60", "-o", "synthesis.robust.enabled=false"]
    demo = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(demo), "-o", "objects=1", "-o", "hands=[allegro]", *fast, *ray_args]) == 0
    assert "1 grasps synthesized, 0 already in" in capsys.readouterr().out
    assert (demo / "contact_sheet.png").is_file() and len(list((demo / "pictures" / "allegro").glob("*.png"))) == 1
    out = tmp_path / "shadow"
    argv = ["retarget", str(demo / "dataset"), "--from", "allegro", "--to", "shadow", "--out", str(out), *ray_args]
    assert cli.main(argv) == 0
    assert "| shadow | sapien | 1 |" in capsys.readouterr().out
    (source,), (target,) = list(open_dataset(demo / "dataset")), list(open_dataset(out))
    assert validate_dataset(out) == [] and target.hand == "shadow" and target.contacts_from == "allegro"
    np.testing.assert_array_equal(target.contacts.positions, source.contacts.positions)
    assert ray.is_initialized()  # the cluster given by --address is left running
