"""docs/tutorials/cross-hand.md, run as the page shows it: a Shadow dataset of three objects, its contacts
retargeted to the Allegro hand, the page's ``compare.py``, and the Allegro's own run as the cross-check the page
states (same contacts, same grasps). Commands and script are read from the page.

Real engines at the page's size (3 objects, SAPIEN, no robust trials): about 30-40 s on 2 loaded cores.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers_tutorial import block_with, commands, ges_commands, ges_runner, tutorial

from ges_core.dataset import open_dataset

from conftest import REPO

PAGE = tutorial("cross-hand.md")
pytestmark = [pytest.mark.sim, pytest.mark.slow]  # real engines, about 10-40 s of CPU
OBJECTS = ("procedural/box/000", "procedural/can/000", "procedural/sphere/000")


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cross_hand")


def test_the_page_commands_in_order(folder: Path) -> None:
    ges = ges_runner(folder)
    cmds = ges_commands(PAGE)
    assert len(cmds) == 5, cmds  # a command added to the page needs its check here
    source, retarget, info, validate, own = cmds
    assert "python compare.py" in commands(PAGE)

    out = ges(*source)
    assert out.returncode == 0, out.stderr
    assert "| shadow | sapien | 3 |" in out.stdout

    out = ges(*retarget)
    assert out.returncode == 0, out.stderr
    assert "| allegro | sapien | 3 |" in out.stdout and "| shadow | sapien | 3 |" in out.stdout  # both rows

    out = ges(*info)
    assert out.returncode == 0, out.stderr
    assert "by hand:      allegro 3\n" in out.stdout
    out = ges(*validate)
    assert out.returncode == 0 and out.stdout.strip() == "runs/allegro-from-shadow: 3 records, no problems"

    (folder / "compare.py").write_text(_script())
    env_python = subprocess.run(
        [sys.executable, "compare.py"],
        cwd=folder,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"},
        timeout=120,
    )
    assert env_python.returncode == 0, env_python.stderr
    lines = env_python.stdout.splitlines()
    assert [ln.split()[0] for ln in lines] == list(OBJECTS)
    for line in lines:
        assert "contacts from shadow, identical: True; joints 24 -> 16;" in line, line

    shadow = open_dataset(folder / "runs" / "shadow")
    crossed = open_dataset(folder / "runs" / "allegro-from-shadow")
    for record in crossed.records(hand="allegro"):  # the same facts, read without the page's script
        assert record.contacts_from == "shadow"
        src = shadow.get(record.object_id, "shadow")
        np.testing.assert_array_equal(record.contacts.positions, src.contacts.positions)
        assert record.steps["contacts"].seconds == pytest.approx(src.steps["contacts"].seconds)  # copied, not rerun

    out = ges(*own)
    assert out.returncode == 0, out.stderr
    mine = open_dataset(folder / "runs" / "allegro-own")
    for record in crossed.records(hand="allegro"):  # the page's claim: the Allegro's own run finds the same grasps
        alone = mine.get(record.object_id, "allegro")
        assert alone.contacts_from is None
        np.testing.assert_allclose(record.contacts.positions, alone.contacts.positions, atol=1e-9)
        np.testing.assert_allclose(record.grasp.wrist_pose, alone.grasp.wrist_pose, atol=1e-6)
        np.testing.assert_allclose(record.grasp.q, alone.grasp.q, atol=1e-6)
        assert record.success == alone.success

    # without --out the Allegro records join the source folder (the page says so)
    shutil.copytree(folder / "runs" / "shadow", folder / "runs" / "both")
    out = ges("retarget", "runs/both", "--from", "shadow", "--to", "allegro", "--no-progress")
    assert out.returncode == 0, out.stderr
    assert "by hand:      allegro 3, shadow 3\n" in ges("dataset", "info", "runs/both").stdout


def _script() -> str:
    """The page's compare.py (the one Python block that opens both datasets)."""
    return block_with(PAGE, "python", 'open_dataset("runs/allegro-from-shadow")')
