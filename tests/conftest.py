"""Shared fixtures: an isolated cache folder and registry files written per test."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
"""Repository root."""
EXAMPLE_HAND_PKG = REPO / "tests" / "data" / "ges_example_hand"
"""Source of the third-party example hand plugin package."""


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
