"""Shared fixtures: an isolated cache folder and registry files written per test."""

from __future__ import annotations

import functools
import importlib
import importlib.util
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
"""Repository root."""
EXAMPLE_HAND_PKG = REPO / "tests" / "data" / "ges_example_hand"
"""Source of the third-party example hand plugin package."""
ABILITY_PKG = REPO / "examples" / "ges-ability-hand" / "ges_ability_hand"
"""Source of the Ability hand package (docs/tutorials/new-hand.md)."""


def benchmark_module(name: str):
    """``benchmarks/NAME.py`` imported as a module, for tests of a benchmark's measure; its folder is on ``sys.path``
    only while it imports (its own ``_results`` and sibling imports)."""
    folder = str(REPO / "benchmarks")
    sys.path.insert(0, folder)
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(folder)


@functools.cache
def _source_module(package_init: Path):
    """The module of a hand package's ``__init__.py``, executed from the repository's source whether or not the
    package is installed (a fresh clone's suite installs none of ``examples/``); once per process."""
    spec = importlib.util.spec_from_file_location(f"_{package_init.parent.name}_source", package_init)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def ability_hand():
    """The Ability hand as ``examples/ges-ability-hand`` builds it, from that source; skips where mani-skill (its
    URDF) is missing."""
    pytest.importorskip("mani_skill")
    return _source_module(ABILITY_PKG / "__init__.py").build_hand()


INSPIRE_PKG = REPO / "examples" / "ges-inspire-hand" / "ges_inspire_hand"
"""Source of the Inspire hand package (docs/hands/inspire.md)."""


def inspire_module():
    """``examples/ges-inspire-hand``'s module, from that source; skips where mani-skill (its URDF) is missing."""
    pytest.importorskip("mani_skill")
    return _source_module(INSPIRE_PKG / "__init__.py")


@pytest.fixture(scope="module")
def unprepared_hands(tmp_path_factory: pytest.TempPathFactory):
    """A cache folder of the module's own, empty: hands load their URDF's own collision shapes, so a
    ``ges hand prepare`` that another test ran in this process (decompositions are found through the cache) does
    not change the hand a physics test checks."""
    patch = pytest.MonkeyPatch()
    patch.setenv("GES_CACHE_DIR", str(tmp_path_factory.mktemp("unprepared_cache")))
    yield
    patch.undo()


@pytest.fixture(scope="session", autouse=True)
def _shared_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keep converted URDFs and decompositions out of the user's cache, shared within the session."""
    import os

    os.environ.setdefault("GES_CACHE_DIR", str(tmp_path_factory.mktemp("ges_cache")))


@pytest.fixture
def write_registry(tmp_path: Path):
    """Write a registry.yaml in a temp folder and return its path."""

    def write(text: str) -> Path:
        path = tmp_path / "registry.yaml"
        path.write_text(text)
        return path

    return write
