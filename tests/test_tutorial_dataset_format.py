"""docs/tutorials/dataset-format.md, run as the page shows it: its dataset (a can the Allegro grasps, the domino
no hand can), the command-line reads, the damaged copy, and the page's two Python scripts, all read from the
page. The scripts' printed facts are cross-checked against the files themselves.

Real engines at the page's size (2 objects, Allegro, SAPIEN, robust trials on): about 15 s of CPU.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers_tutorial import block_with, commands, console_output, ges_commands, ges_runner, tutorial

from conftest import REPO

PAGE = tutorial("dataset-format.md")
pytestmark = [pytest.mark.sim, pytest.mark.slow]  # real engines, about 10-40 s of CPU


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("dataset_format")


def _python(folder: Path, marker: str, name: str) -> str:
    """Write the page's Python block holding ``marker`` to ``name`` in ``folder``, run it, return its output."""
    assert f"python {name}" in commands(PAGE)
    (folder / name).write_text(block_with(PAGE, "python", marker))
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, name], cwd=folder, capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_the_page_in_order(folder: Path) -> None:
    ges = ges_runner(folder)
    cmds = ges_commands(PAGE)
    assert len(cmds) == 4, cmds  # a command added to the page needs its check here
    synth, info, validate, validate_broken = cmds
    records = folder / "runs" / "ds" / "records" / "allegro"

    out = ges(*synth)
    assert out.returncode == 0, out.stderr
    assert "allegro / sapien: contacts: too_low x1" in out.stdout

    names = sorted(p.name for p in records.iterdir())
    assert names == console_output(PAGE, "ls runs/ds/records/allegro").split()  # 8 hex of SHA-256(object, hand)

    out = ges(*info)
    assert out.returncode == 0, out.stderr
    for line in ("by split:     train 1, unseen_category 1", "by category:  can 1, domino 1", "contacts: too_low x1"):
        assert line in out.stdout
    out = ges(*validate)
    assert out.returncode == 0 and out.stdout.strip() == "runs/ds: 2 records, no problems"

    assert "cp -r runs/ds runs/broken" in commands(PAGE)
    assert "echo junk > runs/broken/records/allegro/junk.npz" in commands(PAGE)
    shutil.copytree(folder / "runs" / "ds", folder / "runs" / "broken")
    (folder / "runs" / "broken" / "records" / "allegro" / "junk.npz").write_text("junk\n")
    out = ges(*validate_broken)
    assert out.returncode == 1
    assert out.stdout.strip() == console_output(PAGE, "ges dataset validate runs/broken").strip()
    assert "by hand:      allegro 2\n" in ges("dataset", "info", "runs/broken").stdout  # readers keep going
    resumed = ges(*synth[:-1], "runs/broken", "--no-progress")  # the page: the next run moves the file aside
    assert resumed.returncode == 0, resumed.stderr
    assert (folder / "runs" / "broken" / ".damaged" / "records" / "allegro" / "junk.npz").exists()

    printed = _python(folder, "np.load(path, allow_pickle=False)", "read_npz.py")
    assert printed == console_output(PAGE, "python read_npz.py") + "\n"  # shapes and step codes only: exact
    can = next(records.glob("procedural__can__000-*.npz"))
    with np.load(can, allow_pickle=False) as npz:  # the page's frame claims, checked on the stored numbers
        record = json.loads(str(npz["record_json"]))
        assert len(record["joint_names"]) == npz["q"].shape[0] == 16
        assert np.allclose(np.linalg.norm(npz["contact_normals"], axis=1), 1.0, atol=1e-6)
        assert np.isclose(np.linalg.norm(npz["wrist_pose"][3:]), 1.0, atol=1e-6)
        assert npz["contact_positions"][:, 2].min() > 0.0  # object frame: the table is z = 0, contacts above it

    printed = _python(folder, "from ges_core.dataset import open_dataset", "read_typed.py").splitlines()
    shown = console_output(PAGE, "python read_typed.py").splitlines()
    assert printed[0] == "2 records" and printed[-1] == "validated grasps: (1, 16)"
    assert printed[1].startswith("procedural/can/000: train, ") and "trials ['limits', " in printed[4]
    assert printed[-2] == shown[-2]  # the domino's failure message, word for word
