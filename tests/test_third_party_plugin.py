"""A hand plugin from an outside package appears with no change to this repository.

The example package in ``tests/data/ges_example_hand`` declares the ``ges.plugins`` entry
point. We build it as a real wheel, install the wheel into a private target folder and run
``ges list`` in a fresh interpreter that sees that folder: the same path a user's
``pip install ges-example-hand`` takes, without touching the test environment.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import EXAMPLE_HAND_PKG, REPO


@pytest.fixture(scope="module")
def installed_example(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder with the example plugin's wheel installed into it."""
    root = tmp_path_factory.mktemp("third_party")
    wheels, site = root / "wheels", root / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    src = root / "src"
    subprocess.run(["cp", "-r", str(EXAMPLE_HAND_PKG), str(src)], check=True)  # keep build dirs out of the repo
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(src)], check=True)
    (wheel,) = wheels.glob("ges_example_hand-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True)
    return site


def _ges(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    env.pop("GES_DISABLE_PLUGIN_AUTOLOAD", None)
    return subprocess.run(
        [sys.executable, "-m", "ges_core.cli", *args], env=env, capture_output=True, text=True, cwd=REPO, timeout=120
    )


def test_installed_package_appears_in_ges_list(installed_example):
    result = _ges(installed_example, "list", "hand")
    assert result.returncode == 0, result.stderr
    line = next(ln for ln in result.stdout.splitlines() if "example_gripper" in ln)
    assert "ges-example-hand 0.1.0" in line
    assert "shadow" in result.stdout and "allegro" in result.stdout


def test_installed_hand_builds_through_the_registry(installed_example):
    result = _ges(installed_example, "info", "hand", "example_gripper")
    assert result.returncode == 0, result.stderr
    assert "thumb_j1" in result.stdout and "little" in result.stdout


def test_autoload_off_hides_it(installed_example):
    env_result = subprocess.run(
        [sys.executable, "-m", "ges_core.cli", "list", "hand"],
        env={**os.environ, "PYTHONPATH": f"{installed_example}{os.pathsep}{REPO}", "GES_DISABLE_PLUGIN_AUTOLOAD": "1"},
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert env_result.returncode == 0, env_result.stderr
    assert "example_gripper" not in env_result.stdout and "allegro" in env_result.stdout


def test_no_plugin_blocks_it(installed_example):
    result = _ges(installed_example, "--no-plugin", "example_gripper", "list", "hand")
    assert result.returncode == 0 and "example_gripper" not in result.stdout
