"""Where GES-UniGrasp keeps caches, and how it writes files: atomically, and failing with one clear error.

Every write of the project (dataset records and manifest, pictures, the object and hand caches) goes through
:func:`atomic_write_bytes` and :func:`make_dirs`. An ``OSError`` there (no space, a quota, no permission, a
read-only file system) becomes one :class:`~ges_core.errors.StorageError` naming the path, the cause and what
to do; the temporary file is removed, so a failed write leaves the old file or none, never half of one.
"""

from __future__ import annotations

import errno
import hashlib
import os
import tempfile
from pathlib import Path

from ges_core.errors import StorageError

__all__ = [
    "CACHE_ENV",
    "atomic_write_bytes",
    "atomic_write_text",
    "cache_dir",
    "cache_root",
    "cached_text_file",
    "describe_os_error",
    "file_sha256",
    "make_dirs",
    "storage_error",
]

CACHE_ENV = "GES_CACHE_DIR"
"""Environment variable overriding the cache folder."""


def cache_root() -> Path:
    """``$GES_CACHE_DIR``, default ``~/.cache/ges-unigrasp`` (not created)."""
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "ges-unigrasp")


def cache_dir(*parts: str) -> Path:
    """:func:`cache_root` joined with ``parts``, created (StorageError if it cannot be)."""
    return make_dirs(cache_root().joinpath(*parts))


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


def make_dirs(path: str | Path, *, fix: str | None = None) -> Path:
    """Create the folder ``path`` and its parents if missing; StorageError (with ``fix``) if that fails."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise storage_error(path, exc, fix=fix) from exc
    return path


def atomic_write_bytes(path: str | Path, data: bytes, *, fix: str | None = None) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    A reader sees the old file or the new one, never half of one; a kill leaves no partial file. A failed
    write (full disk, read-only folder, ...) removes its temporary file and raises StorageError naming
    ``path``; ``fix`` replaces the default advice on what to do.
    """
    path, tmp = Path(path), None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600 files; give the usual permissions
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, StorageError):
            raise storage_error(path, exc, fix=fix) from exc
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, fix: str | None = None) -> Path:
    """:func:`atomic_write_bytes` for UTF-8 text."""
    return atomic_write_bytes(path, text.encode("utf-8"), fix=fix)


_CAUSES = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOENT: "no such file or folder",
}
_FULL = (errno.ENOSPC, errno.EDQUOT)
_DENIED = (errno.EACCES, errno.EPERM, errno.EROFS)


def describe_os_error(
    exc: OSError, path: str | Path | None = None, *, doing: str = "writing", fix: str | None = None
) -> str:
    """One line for an OSError: the cause, what was being done to which path, and what to do.

    >>> describe_os_error(OSError(errno.ENOSPC, "No space left on device"), "runs/x/manifest.json")
    'no space left on device writing runs/x/manifest.json; free space there or write to another folder'
    """
    path = path if path is not None else exc.filename
    cause = _CAUSES.get(exc.errno) or exc.strerror or f"{type(exc).__name__}: {exc}"
    where = f" {doing} {path}".rstrip() if path is not None else ""
    return f"{cause}{where}; {fix or _advice(exc.errno, path, writing=doing == 'writing')}"


def storage_error(path: str | Path, exc: OSError, *, fix: str | None = None) -> StorageError:
    """The StorageError of a failed write of ``path`` (see :func:`describe_os_error`)."""
    return StorageError(describe_os_error(exc, path, fix=fix), path=str(path), errno=exc.errno)


def _advice(code: int | None, path: str | Path | None, *, writing: bool) -> str:
    """What to do about an OSError of errno ``code`` at ``path`` (the cache folder gets its own advice)."""
    in_cache = path is not None and _inside(Path(path), cache_root())
    elsewhere = f"set {CACHE_ENV} to another folder" if in_cache else "write to another folder"
    if code in _FULL:
        return f"free space there or {elsewhere}" if writing else "free space on that disk"
    if code in _DENIED:
        return f"make it writable or {elsewhere}" if writing else "check its permissions"
    return "check that path and the disk it is on"


def _inside(path: Path, folder: Path) -> bool:
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except OSError:  # a path that cannot be resolved is not known to be inside
        return False


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
