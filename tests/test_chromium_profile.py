"""A headless Chromium's profile folder is removed even while its helper processes still write into it (the viewer
test once failed in CI on ``Directory not empty: 'Default'`` after the browser had exited)."""

from __future__ import annotations

import tempfile
import threading
import time

import pytest

from ges_core.errors import BackendUnavailable
from ges_core.viewer import chromium
from ges_core.viewer.chromium import remove_profile


def test_a_profile_still_being_written_is_removed(tmp_path):
    """A thread keeps creating files in ``profile/Default`` for 0.3 s, as Chromium's helpers do after the browser
    exits; removing the folder meanwhile must not raise, and the folder is gone once the writer has stopped (it
    stops when the folder it writes into has vanished)."""
    profile = tmp_path / "ges-chromium-test"
    (profile / "Default").mkdir(parents=True)
    for i in range(200):
        (profile / "Default" / f"old_{i}").write_text("x")
    stop = time.monotonic() + 0.3

    def write() -> None:
        i = 0
        while time.monotonic() < stop:
            try:
                (profile / "Default" / f"new_{i}").write_text("x")
            except FileNotFoundError:
                return
            i += 1

    writer = threading.Thread(target=write)
    writer.start()
    remove_profile(profile)
    writer.join()
    remove_profile(profile)  # whatever the writer made after the removal; and a folder already gone is no error
    assert not profile.exists()


def test_removing_a_missing_profile_is_harmless(tmp_path):
    remove_profile(tmp_path / "never-made")
    assert not (tmp_path / "never-made").exists()


def test_a_browser_that_cannot_start_leaves_no_profile(tmp_path, monkeypatch):
    """Without Chromium, HeadlessPage and screenshot raise BackendUnavailable and leave no profile folder behind."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(chromium, "find_chromium", lambda: None)
    with pytest.raises(BackendUnavailable, match="no Chromium found"):
        chromium.HeadlessPage()
    with pytest.raises(BackendUnavailable, match="no Chromium found"):
        chromium.screenshot("http://127.0.0.1:1", tmp_path / "shot.png")
    assert list(tmp_path.iterdir()) == []
