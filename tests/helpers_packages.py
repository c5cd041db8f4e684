"""Outside example packages (``examples/ges-*``) installed as a user would, for the tests that run them.

When the environment already holds the distribution (``pip install -e examples/NAME``) it is used as it is;
otherwise the package is built as a real wheel (``pip wheel --no-deps --no-build-isolation``) and installed with
``pip install --no-deps --target`` into a temporary folder that fresh interpreters see through ``PYTHONPATH``
(the environment is left untouched). Either way its plugins come in through their ``ges.plugins`` entry point.
"""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from conftest import REPO

__all__ = ["example_site", "interpreter"]


def _installed(distribution: str) -> bool:
    try:
        importlib.metadata.distribution(distribution)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def example_site(folder: str, distribution: str, tmp: Path) -> Path | None:
    """Folder holding ``examples/<folder>``'s installed wheel, or None when the environment already has it.

    ``distribution``: its pip name (``ges-mujoco-sim``); ``tmp``: an empty scratch folder of the test session.
    """
    if _installed(distribution):
        return None
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    src = tmp / "src"
    # a copy, so that the build's folders stay out of the repository
    subprocess.run(["cp", "-r", str(REPO / "examples" / folder), str(src)], check=True)
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp / "w"), str(src)], check=True)
    (wheel,) = (tmp / "w").glob(distribution.replace("-", "_") + "-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(tmp / "site"), str(wheel)], check=True)
    return tmp / "site"


def interpreter(site: Path | None, prefix: tuple[str, ...] = ()) -> Callable[..., subprocess.CompletedProcess]:
    """``call(*args)``: ``python *prefix *args`` in a fresh interpreter that sees the package and loads outside
    plugins (``GES_DISABLE_PLUGIN_AUTOLOAD`` removed), run in the repository; the finished process, output as text.
    """
    paths = [str(site)] if site else []
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([*paths, str(REPO)]), "OMP_NUM_THREADS": "1"}
    env.pop("GES_DISABLE_PLUGIN_AUTOLOAD", None)

    def call(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, *prefix, *args], env=env, capture_output=True, text=True, cwd=REPO, timeout=600
        )

    return call
