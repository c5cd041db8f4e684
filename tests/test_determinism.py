"""Run-to-run determinism of Stage 1: the same object gives the same record, byte for byte, in two fresh processes.

The two runs differ in everything that must not matter: the hash seed (PYTHONHASHSEED), the objects
before it in its chunk (a simulator reused across objects once made ``procedural/can/001`` depend on
``pybullet/random_urdfs/002`` run before it), and the run's object list (as in a resumed run).
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

TARGET = "procedural/ellipsoid/000"
"""Any object whose grasp reaches refinement and validation. The history case was procedural/can/001 (its
refined grasp moved 15-24 mm after another object in a reused scene); since the wrist search's table check
its Allegro grasp stops at retargeting (unreachable), so it no longer exercises the simulators."""

_SCRIPT = textwrap.dedent(
    """
    import hashlib, pathlib, pickle, sys
    from ges_core.dataset import open_dataset, record_relpath
    from ges_core.synthesis import SynthesisConfig, run_synthesis
    out, ids = sys.argv[1], sys.argv[2].split(",")
    config = SynthesisConfig.model_validate({"validate": {"hold_steps": 60}})
    run_synthesis(ids, ["allegro"], config, out)
    record = open_dataset(out).get(sys.argv[3], "allegro")
    data = (pathlib.Path(out) / record_relpath(sys.argv[3], "allegro")).read_bytes()
    sys.stdout.buffer.write(pickle.dumps((record, hashlib.sha256(data).hexdigest())))
    """
)


def _record(tmp_path, name: str, ids: list[str], hash_seed: str):
    env = {**os.environ, "PYTHONHASHSEED": hash_seed}
    out = tmp_path / name
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT, str(out), ",".join(ids), TARGET], env=env, capture_output=True, check=False
    )
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    return pickle.loads(done.stdout)


def _arrays(record) -> dict[str, np.ndarray]:
    return {
        "contacts": record.contacts.positions,
        "grasp_q": record.grasp.q,
        "grasp_wrist": record.grasp.wrist_pose,
        "pregrasp_q": record.pregrasp.q,
        "pregrasp_wrist": record.pregrasp.wrist_pose,
    }


def _outcomes(record) -> dict:
    steps = {name: (s.ok, s.reason) for name, s in record.steps.items()}
    return {
        "steps": steps,
        "flags": dict(record.validation_flags),
        "frozen": None if record.refinement is None else record.refinement.frozen,
    }


@pytest.mark.sim
def test_same_record_in_two_processes_whatever_ran_before(tmp_path):
    alone, alone_sha = _record(tmp_path, "alone", [TARGET], "1")
    after, after_sha = _record(tmp_path, "after", ["pybullet/random_urdfs/002", TARGET], "2")
    assert alone_sha == after_sha  # the same file: its times live beside it (issue 10, point 8)
    assert alone.steps["refinement"].attempted  # the simulator part ran, so the comparison covers it
    for name, array in _arrays(alone).items():
        np.testing.assert_array_equal(array, _arrays(after)[name], err_msg=name)
    assert _outcomes(alone) == _outcomes(after)
    assert alone.quality == after.quality
