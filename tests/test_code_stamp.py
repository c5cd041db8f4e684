"""The code stamp of matrix cells names the last commit that changed the code, not HEAD."""

from __future__ import annotations

import subprocess

from ges_core.experts.evaluate import code_changes_since, git_code_stamp


def _git(root, *args):
    env = ["-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    return subprocess.run(["git", *env, *args], cwd=root, check=True, capture_output=True, text=True).stdout.strip()


def test_a_docs_commit_keeps_the_stamp_and_a_code_change_moves_it(tmp_path):
    _git(tmp_path, "init", "-q")
    (tmp_path / "ges_core").mkdir()
    (tmp_path / "ges_core" / "a.py").write_text("x = 1\n")
    (tmp_path / "README.md").write_text("hi\n")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-q", "-m", "code")
    code_commit = _git(tmp_path, "rev-parse", "HEAD")[:12]
    assert git_code_stamp(tmp_path) == code_commit

    (tmp_path / "README.md").write_text("more docs\n")
    _git(tmp_path, "commit", "-q", "-am", "docs only")
    assert _git(tmp_path, "rev-parse", "HEAD")[:12] != code_commit
    assert git_code_stamp(tmp_path) == code_commit  # the matrix stays reusable after a docs commit

    (tmp_path / "ges_core" / "a.py").write_text("x = 2\n")  # uncommitted code change
    dirty = git_code_stamp(tmp_path)
    assert dirty.startswith(code_commit + "+") and len(dirty) == 12 + 1 + 8
    (tmp_path / "registry.yaml").write_text("defaults: {}\n")
    _git(tmp_path, "add", "registry.yaml")
    assert git_code_stamp(tmp_path) != dirty  # the registry's defaults count as code

    _git(tmp_path, "commit", "-q", "-am", "code again")
    assert git_code_stamp(tmp_path) == _git(tmp_path, "rev-parse", "HEAD")[:12] != code_commit


def test_code_changes_since_lists_the_code_files_that_differ_and_nothing_else(tmp_path):
    """What --accept-code shows: code files changed since a stamp's commit, committed or not; docs are not code."""
    _git(tmp_path, "init", "-q")
    (tmp_path / "ges_core").mkdir()
    for name in ("a.py", "b.py"):
        (tmp_path / "ges_core" / name).write_text("x = 1\n")
    (tmp_path / "README.md").write_text("hi\n")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-q", "-m", "code")
    stamp = git_code_stamp(tmp_path)
    assert code_changes_since(stamp, tmp_path) == []
    (tmp_path / "ges_core" / "b.py").write_text("x = 2\n")
    (tmp_path / "README.md").write_text("more\n")
    _git(tmp_path, "commit", "-q", "-am", "code and docs")
    (tmp_path / "registry.yaml").write_text("defaults: {}\n")
    _git(tmp_path, "add", "registry.yaml")
    assert code_changes_since(stamp, tmp_path) == ["ges_core/b.py", "registry.yaml"]
    assert code_changes_since(git_code_stamp(tmp_path), tmp_path) is None  # a stamp of uncommitted code
    assert code_changes_since("0123456789ab", tmp_path) is None  # a commit git does not know
    assert code_changes_since("version 0.1.0", tmp_path) is None
