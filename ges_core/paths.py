"""Where GES-UniGrasp keeps caches, and how it writes files atomically."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

__all__ = ["CACHE_ENV", "atomic_write_bytes", "atomic_write_text", "cache_dir", "cached_text_file", "file_sha256"]

CACHE_ENV = "GES_CACHE_DIR"
"""Environment variable overriding the cache folder."""


def cache_dir(*parts: str) -> Path:
    """``$GES_CACHE_DIR`` (default ``~/.cache/ges-unigrasp``) joined with ``parts``, created."""
    root = Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "ges-unigrasp")
    path = root.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def file_sha256(path: str | Path, *, length: int = 16) -> str:
    """First ``length`` hex digits of the SHA-256 of a file's bytes (cache keys)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:length]


def cached_text_file(text: str, *folder: str, stem: str, suffix: str = ".urdf") -> Path:
    """``cache_dir(*folder)/{stem}_{hash of text}{suffix}``, written once (atomically) and reused."""
    key = hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
    path = cache_dir(*folder) / f"{stem}_{key}{suffix}"
    if not path.is_file():
        atomic_write_text(path, text)
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    A reader sees the old file or the new one, never half of one; a kill leaves no partial file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600 files; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """:func:`atomic_write_bytes` for UTF-8 text."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
