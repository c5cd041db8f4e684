"""Shared helpers of the tutorial tests (tests/test_tutorial_*.py): read a tutorial's commands and files from
its Markdown, and run ``ges`` the way a user types it, in a fresh interpreter.

The tests take the commands *from the page* (the ``$ `` lines of its ``console`` blocks) so that a tutorial
cannot drift from what its test runs: a command renamed on the page and not in the product fails the test.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from conftest import REPO

TUTORIALS = REPO / "docs" / "tutorials"
"""Folder of the tutorials."""

_FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.M | re.S)


def tutorial(name: str) -> str:
    """The Markdown text of ``docs/tutorials/<name>``."""
    return (TUTORIALS / name).read_text()


def blocks(text: str, lang: str) -> list[str]:
    """Bodies of the fenced code blocks of language ``lang`` (```` ```yaml ```` ...), in page order."""
    return [m.group(2) for m in _FENCE.finditer(text) if m.group(1) == lang]


def block_with(text: str, lang: str, marker: str) -> str:
    """The one ``lang`` block containing ``marker``; AssertionError when none or several do."""
    found = [b for b in blocks(text, lang) if marker in b]
    assert len(found) == 1, f"{len(found)} {lang} blocks contain {marker!r}"
    return found[0]


def commands(text: str) -> list[str]:
    """Every ``$ `` command of the page's ``console`` blocks, in order, ``\\``-continued lines joined."""
    out: list[str] = []
    for body in blocks(text, "console"):
        lines = body.splitlines()
        i = 0
        while i < len(lines):
            line = lines[i]
            if line.startswith("$ "):
                cmd = line[2:]
                while cmd.endswith("\\") and i + 1 < len(lines):
                    i += 1
                    cmd = cmd[:-1].rstrip() + " " + lines[i].strip()
                out.append(cmd)
            i += 1
    return out


def ges_commands(text: str) -> list[list[str]]:
    """The page's ``ges ...`` commands as argument lists (without the leading ``ges``)."""
    return [shlex.split(c)[1:] for c in commands(text) if c.startswith("ges ")]


def ges_runner(cwd: Path) -> Callable[..., subprocess.CompletedProcess]:
    """A function running ``ges ARGS`` in ``cwd`` in a fresh interpreter (``python -m ges_core.cli``).

    The environment is the test session's (its ``GES_CACHE_DIR`` included, see conftest) with the checkout on
    ``PYTHONPATH`` and one OpenMP thread, as the project's rules ask. Installed outside plugins are not loaded
    (``GES_DISABLE_PLUGIN_AUTOLOAD=1``): the tutorials use the built-in hands and simulators, and their printed
    lists (``Known sims: pybullet, sapien``) must not depend on what else the environment holds.
    """
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "GES_DISABLE_PLUGIN_AUTOLOAD": "1"}
    env.pop("GES_REGISTRY", None)  # the pages use ./registry.yaml of the folder they work in

    def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "ges_core.cli", *args],
            env=env,
            capture_output=True,
            text=True,
            cwd=cwd,
            timeout=timeout,
        )

    return run


def console_output(text: str, command: str) -> str:
    """The output the page shows under ``$ command`` (up to the next ``$ `` line or the block's end)."""
    for body in blocks(text, "console"):
        lines = body.splitlines()
        for i, line in enumerate(lines):
            if line == f"$ {command}":
                rest = []
                for later in lines[i + 1 :]:
                    if later.startswith("$ "):
                        break
                    rest.append(later)
                return "\n".join(rest)
    raise AssertionError(f"the page shows no `$ {command}`")
