"""docs/tutorials/architecture.md: every module, path and ``ges`` command the page and its picture name exists,
the committed picture is what docs/tutorials/make_architecture.py draws, and the page's outputs (``ges list``,
``layers.py``) are what the code prints. About 10 s (one small Stage 1 run in layers.py).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers_tutorial import TUTORIALS, block_with, commands, console_output, ges_commands, ges_runner, tutorial

import ges_core
from ges_core import hookspecs
from ges_core.cli import build_parser

from conftest import REPO

PAGE = tutorial("architecture.md")
PATH = re.compile(r"`((?:ges_core|plugins|examples|tests|docs|configs|benchmarks)/[\w./-]*)`")
DOC = re.compile(r"\b(docs/[\w/-]+\.md)\b")
COMMAND = re.compile(r"`ges ([a-z][a-z-]*)(?: ([a-z][a-z-]*))?")


@functools.cache
def _script():
    """docs/tutorials/make_architecture.py as a module (registered, as its dataclass needs)."""
    spec = importlib.util.spec_from_file_location("make_architecture", TUTORIALS / "make_architecture.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(actions[0].choices) if actions else {}


def test_every_path_the_page_and_picture_name_exists() -> None:
    named = set(PATH.findall(PAGE)) | set(DOC.findall(PAGE))
    named |= {m for box in _script().BOXES for m in box.modules}
    assert len(named) > 30  # the page and picture name the parts; a broken regex would find nothing
    missing = sorted(p for p in named if not (REPO / p.rstrip("/")).exists())
    assert not missing, f"named on the page or in the picture but not in the repository: {missing}"
    for link in re.findall(r"\]\(([\w.-]+\.(?:md|py|png))\)", PAGE):  # relative links beside the page
        assert (TUTORIALS / link).exists(), link


def test_every_command_and_name_exists() -> None:
    top = _subcommands(build_parser())
    found = COMMAND.findall(PAGE)
    assert len(found) >= 8
    for word, sub in found:
        assert word in top, f"`ges {word}` on the page is not a command"
        subs = _subcommands(top[word])
        if sub and subs:
            assert sub in subs, f"`ges {word} {sub}` on the page is not a command"
    script = _script()
    hooks = next(b for b in script.BOXES if b.key == "hooks").lines
    for hook in hooks:  # the hook names in the picture are the real hooks
        assert callable(getattr(hookspecs, hook)), hook
    for words in next(b for b in script.BOXES if b.key == "ifaces").lines:
        for name in re.findall(r"[A-Z]\w+", words):  # HandModel, SimBackend, ContactSet, Expert, ...
            modules = ("ges_core.hand", "ges_core.sim", "ges_core.contact", "ges_core.policy")
            assert any(hasattr(importlib.import_module(m), name) for m in modules), name


def test_the_picture_is_what_the_script_draws(tmp_path: Path) -> None:
    import matplotlib
    from PIL import Image

    committed = TUTORIALS / "architecture.png"
    assert "](architecture.png)" in PAGE
    script = _script()
    drawn = script.draw(tmp_path / "architecture.png")
    with Image.open(committed) as a, Image.open(drawn) as b:
        assert a.size == b.size == (1600, 1000)
    if matplotlib.__version__ == script.DRAWN_WITH:
        assert drawn.read_bytes() == committed.read_bytes(), "rerun docs/tutorials/make_architecture.py and commit"


@pytest.mark.sim
def test_the_page_outputs(tmp_path: Path) -> None:
    ges = ges_runner(tmp_path)
    cmds = ges_commands(PAGE)
    assert cmds == [["list", "hand"], ["list", "sim"]], cmds
    for cmd in cmds:
        out = ges(*cmd)
        shown = console_output(PAGE, "ges " + " ".join(cmd)).replace("0.1.0", ges_core.__version__)
        assert out.stdout.strip() == shown.strip()

    assert "python layers.py" in commands(PAGE)
    (tmp_path / "layers.py").write_text(block_with(PAGE, "python", "run_synthesis("))
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "GES_DISABLE_PLUGIN_AUTOLOAD": "1"}
    out = subprocess.run([sys.executable, "layers.py"], cwd=tmp_path, capture_output=True, text=True, env=env,
                         timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr
    printed, shown = out.stdout.splitlines(), console_output(PAGE, "python layers.py").splitlines()
    assert printed[:2] == shown[:2]  # names and counts: exact
    assert printed[2].startswith("allegro sapien {'contacts': 'ok', ") and "'robust': 'not_run'" in printed[2]


def test_the_index_lists_every_tutorial() -> None:
    """docs/tutorials/README.md links every page of the folder, and the project README links the index."""
    index = tutorial("README.md")
    pages = sorted(p.name for p in TUTORIALS.glob("*.md") if p.name != "README.md")
    assert len(pages) >= 6
    for page in pages:
        assert f"]({page})" in index, page
    assert "docs/tutorials/README.md" in (REPO / "README.md").read_text()
