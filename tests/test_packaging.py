"""Packaging as a pip user meets it: a checkout that was not installed, a missing engine, a built wheel.

Each test runs ``ges`` in a real virtual environment under ``tmp_path`` whose site-packages sees the test
environment's packages through a folder of symlinks, minus the ones a case leaves out: always this
project's own editable install, and PyBullet where the engine is to be missing. Nothing is downloaded and
the test environment is not touched.
"""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from collections.abc import Iterable
from pathlib import Path

import pytest

from conftest import REPO

OWN = "ges-unigrasp"
PYBULLET_HINT = "pip install 'ges-unigrasp[pybullet]'"


def _top_level_names(dist_name: str) -> set[str]:
    """The entries a distribution put at the top of site-packages (its packages, modules, dist-info)."""
    files = importlib.metadata.distribution(dist_name).files or []
    return {f.parts[0] for f in files} - {"..", "__pycache__"}


def _make_venv(root: Path, *, without: Iterable[str] = ()) -> Path:
    """A venv at ``root/venv`` seeing this environment's site-packages except ``ges-unigrasp`` and ``without``.

    Returns the venv's python. The packages are symlinks in ``root/deps``, added by a ``.pth`` file with
    ``site.addsitedir`` so that their own ``.pth`` files still run.
    """
    left_out = set().union(*(_top_level_names(d) for d in (OWN, *without)))
    deps = root / "deps"
    deps.mkdir(parents=True)
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        if entry.name not in left_out:
            (deps / entry.name).symlink_to(entry)
    venv = root / "venv"
    try:
        subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, capture_output=True)
    except (subprocess.CalledProcessError, OSError) as exc:
        pytest.skip(f"cannot create a virtual environment here: {exc}")
    python = venv / "bin" / "python"
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    Path(site, "ges_test_deps.pth").write_text(f"import site; site.addsitedir({str(deps)!r})\n")
    return python


def _run(argv: list, *, cwd: Path, pythonpath: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``argv`` in ``cwd`` (outside the checkout) with a clean plugin environment."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "GES_DISABLE_PLUGIN_AUTOLOAD", "GES_REGISTRY")
    }
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


# -- a checkout that was not pip-installed, without PyBullet -------------------------------------------
@pytest.fixture(scope="module")
def no_pybullet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(python of a venv without PyBullet and without this project installed, a folder outside the checkout)."""
    root = tmp_path_factory.mktemp("no_pybullet")
    python = _make_venv(root, without=["pybullet"])
    probe = _run([python, "-c", "import pybullet"], cwd=root)
    assert probe.returncode != 0, "pybullet is still importable: the test venv is not isolated"
    return python, root


def test_checkout_lists_builtins_and_says_what_to_install(no_pybullet):
    python, cwd = no_pybullet
    result = _run([python, "-m", "ges_core.cli", "list"], cwd=cwd, pythonpath=REPO)
    assert result.returncode == 0, result.stderr
    lines = {line[2:].split()[0]: line for line in result.stdout.splitlines() if line[:2] in ("  ", " *")}
    assert {"shadow", "allegro", "sapien", "pybullet"} <= set(lines), result.stdout
    assert f"[needs: {PYBULLET_HINT}]" in lines["pybullet"]
    assert "needs" not in lines["sapien"] and "built-in, ges-unigrasp" in lines["sapien"]


def test_missing_engine_is_one_error_line(no_pybullet):
    python, cwd = no_pybullet
    result = _run([python, "-m", "ges_core.cli", "sim", "check", "--hand", "allegro", "--sim", "pybullet"], cwd=cwd,
                  pythonpath=REPO)  # fmt: skip
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("ges: error: ") and result.stderr.count("\n") == 1, result.stderr
    assert "sim 'pybullet' needs 'pybullet'" in result.stderr and PYBULLET_HINT in result.stderr


# -- a built wheel ----------------------------------------------------------------------------------
SOURCES = ("ges_core", "plugins", "pyproject.toml", "setup.py", "README.md")
"""What the wheel is built from (copied, so that no build folder lands in the checkout)."""


def _package_files() -> set[str]:
    """Every file of the checkout's packages as the wheel should hold it (``plugins/`` as ``ges_plugins/``)."""
    found = set()
    for folder, name in (("ges_core", "ges_core"), ("plugins", "ges_plugins")):
        for path in (REPO / folder).rglob("*"):
            if path.is_file() and "__pycache__" not in path.parts and path.suffix in (".py", ".yaml", ".urdf"):
                found.add(f"{name}/{path.relative_to(REPO / folder).as_posix()}")
    return found


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A wheel of the checkout, built without build isolation (no download)."""
    root = tmp_path_factory.mktemp("wheel")
    (root / "src").mkdir()
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, root / "src" / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(REPO / name, root / "src" / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", root / "dist", root / "src"], check=True)
    (built,) = (root / "dist").glob("ges_unigrasp-*.whl")
    return built


@pytest.mark.slow
def test_wheel_holds_the_packages_under_their_installed_names(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert _package_files() <= names, sorted(_package_files() - names)
    assert not any(n.startswith("plugins/") for n in names)
    assert {"ges_plugins/hands/shadow/shadow.yaml", "ges_plugins/hands/allegro/allegro.yaml"} <= names
    metadata = next(n for n in names if n.endswith(".dist-info/METADATA"))
    text = zipfile.ZipFile(wheel).read(metadata).decode()
    for extra in ("sapien", "pybullet", "allegro", "shadow", "all"):
        assert f"Provides-Extra: {extra}" in text


@pytest.mark.slow
def test_installed_wheel_runs_the_demo(wheel, tmp_path):
    python = _make_venv(tmp_path / "env")
    subprocess.run(
        [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "--python", python, "install",
         "--no-deps", "--no-index", wheel],
        check=True,
    )  # fmt: skip
    ges, cwd = python.parent / "ges", tmp_path
    where = _run(
        [python, "-c", "import ges_core, ges_plugins; print(ges_core.__file__, ges_plugins.__file__)"], cwd=cwd
    )
    assert where.returncode == 0 and str(REPO) not in where.stdout, where.stdout + where.stderr
    info = _run([ges, "info", "sim", "pybullet"], cwd=cwd)
    assert info.returncode == 0, info.stderr
    assert "settings: solver_iterations=100" in info.stdout  # the tuned value travels with the plugin
    assert "built-in, ges-unigrasp" in info.stdout
    demo = _run([ges, "demo", "-o", "objects=1", "-o", f"out={tmp_path / 'demo'}", "--no-progress"], cwd=cwd)
    assert demo.returncode == 0, demo.stderr
    assert "2 grasps synthesized" in demo.stdout and (tmp_path / "demo" / "table.md").is_file()
