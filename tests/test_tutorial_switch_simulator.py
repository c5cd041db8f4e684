"""docs/tutorials/switch-simulator.md, run as the page shows it: every ``ges`` command of the page, read from
the page, in a folder holding a copy of the registry and the page's Stage 1 YAML.

Real engines at the page's size (two objects, one hand, no robust trials): about 40 s on 2 loaded cores.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
import yaml
from helpers_tutorial import block_with, console_output, ges_commands, ges_runner, tutorial

from ges_core.dataset import open_dataset

from conftest import REPO

PAGE = tutorial("switch-simulator.md")
pytestmark = [pytest.mark.sim, pytest.mark.slow]  # real engines, about 10-40 s of CPU
COMMANDS = ges_commands(PAGE)


def _error_line(proc) -> str:
    return next(ln for ln in proc.stderr.splitlines() if ln.startswith("ges: error:"))


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reader's folder: a copy of registry.yaml and the page's stage1-pybullet.yaml."""
    root = tmp_path_factory.mktemp("sims")
    shutil.copy(REPO / "registry.yaml", root / "registry.yaml")
    (root / "stage1-pybullet.yaml").write_text(block_with(PAGE, "yaml", "refine_sim: pybullet"))
    return root


def _set_default_as_the_page_says(folder: Path) -> None:
    """Edit the copy's ``defaults.sim`` line to the page's line (step 2), leaving the rest of the file alone."""
    new = next(ln for ln in block_with(PAGE, "yaml", "defaults:").splitlines() if ln.strip().startswith("sim:"))
    path = folder / "registry.yaml"
    text, n = re.subn(r"^  sim: sapien .*$", new, path.read_text(), count=1, flags=re.M)
    assert n == 1, "registry.yaml no longer has the `  sim: sapien` line the page edits"
    path.write_text(text)
    assert yaml.safe_load(text)["defaults"]["sim"] == "pybullet"


def test_the_page_commands_in_order(folder: Path) -> None:
    ges = ges_runner(folder)
    assert len(COMMANDS) == 12, COMMANDS  # a command added to the page needs its check here
    listed, check, listed_after, check_after, once, info, synth, refused, typo, base_pb, base_sp, unknown = COMMANDS

    out = ges(*listed)
    assert out.returncode == 0, out.stderr
    assert " *sapien " in out.stdout and "  pybullet " in out.stdout
    out = ges(*check)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "hand allegro in sapien: 330 steps" in out.stdout and out.stdout.rstrip().endswith("OK")

    _set_default_as_the_page_says(folder)
    out = ges(*listed_after)
    assert " *pybullet " in out.stdout and "  sapien " in out.stdout, out.stdout
    out = ges(*check_after)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "hand allegro in pybullet: 330 steps" in out.stdout and out.stdout.rstrip().endswith("OK")
    out = ges(*once)
    assert "hand allegro in sapien" in out.stdout and "pybullet" not in out.stdout

    out = ges(*info)
    assert out.stdout.strip() == console_output(PAGE, "ges info sim pybullet").strip()

    out = ges(*synth)
    assert out.returncode == 0, out.stderr
    assert "| allegro | pybullet | 2 |" in out.stdout
    assert "cross-engine agreement, allegro (pybullet vs sapien)" in out.stdout
    records = list(open_dataset(folder / "runs" / "pybullet"))
    assert len(records) == 2
    for record in records:  # refined in PyBullet, judged by both engines (independent of the printed table)
        assert record.simulator == "pybullet" and set(record.validations) == {"pybullet", "sapien"}
        assert record.steps["refinement"].ok, record.steps
    assert sum(r.validations["pybullet"].success for r in records) >= 1

    for cmd in (refused, typo):  # the page shows the exact one-line errors
        out = ges(*cmd)
        assert out.returncode == 1
        assert _error_line(out) in console_output(PAGE, "ges " + " ".join(cmd))
    assert not (folder / "runs" / "typo").exists()  # refused before anything is written

    out = ges(*base_pb)
    assert out.returncode == 0, out.stderr
    assert "| hand allegro | sim pybullet |" in out.stdout
    row = next(ln for ln in out.stdout.splitlines() if ln.startswith("| all |"))
    assert row.startswith("| all | 2/2 | 2 |"), row
    out = ges(*base_sp)
    assert out.returncode == 0, out.stderr
    assert "| hand allegro | sim sapien |" in out.stdout
    stored = sorted(p.name for p in (folder / "runs" / "baseline").glob("*.json"))
    assert stored == ["baseline-allegro-pybullet.json", "baseline-allegro-sapien.json"]

    out = ges(*unknown)
    assert out.returncode == 1 and _error_line(out) in PAGE


def test_engine_settings_block_reaches_the_plugin(tmp_path: Path) -> None:
    """Step 3: the page's ``settings.sim.pybullet`` block in a registry copy, shown by ``ges info``, and its
    ``--set`` twin; a wrong type is refused when the simulator is built, naming the key."""
    registry = yaml.safe_load((REPO / "registry.yaml").read_text())
    registry["settings"] = yaml.safe_load(block_with(PAGE, "yaml", "solver_iterations: 50"))["settings"]
    (tmp_path / "registry.yaml").write_text(yaml.safe_dump(registry))
    ges = ges_runner(tmp_path)
    assert "settings: solver_iterations=50" in ges("info", "sim", "pybullet").stdout
    assert (
        "settings: solver_iterations=50"
        in ges(
            "--registry",
            str(REPO / "registry.yaml"),
            "--set",
            "settings.sim.pybullet.solver_iterations=50",
            "info",
            "sim",
            "pybullet",
        ).stdout
    )
    bad = ges(
        "--set", "settings.sim.pybullet.solver_iterations=abc", "sim", "check", "--hand", "allegro", "--sim", "pybullet"
    )
    assert bad.returncode == 1 and "settings.sim.pybullet.solver_iterations" in _error_line(bad)
