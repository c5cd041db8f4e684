"""One writer per dataset folder: an exclusive lock on ``<folder>/.lock`` for the writer's lifetime.

The mechanism is ``fcntl.flock`` (exclusive, non-blocking) on the lock file; the file's content (pid, host,
start time, command) only names the holder in messages. ``flock`` rather than creating the file with
``O_CREAT | O_EXCL``: the kernel drops the lock when its holder exits however it exits (``kill -9``, a crash, a
power cut), so a dead run never leaves a lock that blocks the next one, and no pid has to be guessed alive (a
pid reused by another program would keep an ``O_EXCL`` lock forever). A lock file left behind by a dead holder
is therefore just a file: the next writer takes it over and says so.

Caveat, network file systems: on Linux, ``flock`` on NFS is turned into a POSIX lock that the server arbitrates
between machines (NFS v3 with ``lockd``, v4 natively), so two hosts exclude each other; on a mount with
``nolock``, or on file systems that keep locks per machine, each machine only sees its own locks and two hosts
can both write. The holder's host in the lock file then is the only hint; a lock held by a machine that
crashed is released when the server's lease expires (NFS v4: about 90 s), or by deleting the lock file.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shlex
import socket
import sys
import time
from pathlib import Path

from ges_core.dataset.layout import utc_now
from ges_core.errors import LockError
from ges_core.paths import storage_error

__all__ = ["LOCK_FILE", "FolderLock", "holder_info"]

LOCK_FILE = ".lock"
HOLDER_WAIT_S = 1.0
"""How long a refused writer waits for the holder's name: it writes it right after taking the lock (microseconds),
so only a refusal in that instant waits at all."""
_ATTEMPTS = 5
"""Tries when the lock file is replaced between opening and locking it (its holder removing it on close)."""


class FolderLock:
    """An exclusive lock on ``folder/.lock``, taken by :meth:`acquire`, given back by :meth:`release`."""

    def __init__(self, path: Path, fd: int, notes: list[str]) -> None:
        self.path, self._fd = path, fd
        self.notes = notes
        """What taking the lock found: a lock file left by a holder that is gone."""

    @classmethod
    def acquire(cls, folder: Path) -> FolderLock:
        """Lock ``folder`` (which must exist); LockError naming the holder if another process has it, StorageError
        if the lock file cannot be written."""
        path = folder / LOCK_FILE
        for _ in range(_ATTEMPTS):
            fd = _open(path)
            try:
                if _locked(fd, path):
                    return cls(path, fd, _take_over(fd, path))
            except BaseException:
                os.close(fd)
                raise
            os.close(fd)  # the file we locked was removed meanwhile: lock the new one
        raise LockError(f"cannot lock {path}: the file keeps being replaced; is another program deleting it?")

    def release(self) -> None:
        """Remove the lock file and give the lock back (safe to call twice)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if _same_file(fd, self.path):
                self.path.unlink()  # before unlocking: a waiter that opened this file sees it replaced and retries
        except OSError:
            pass  # a read-only folder now: the lock file stays, and the next writer takes it over
        finally:
            os.close(fd)  # closing drops the lock

    def __del__(self) -> None:  # an abandoned writer gives its folder back when collected
        with contextlib.suppress(Exception):  # nothing to report to at collection time
            self.release()


def holder_info() -> dict:
    """What this process writes into a lock file it holds."""
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": utc_now(),
        "command": shlex.join(sys.argv)[:300],
    }


def _open(path: Path) -> int:
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise storage_error(path, exc) from exc


def _locked(fd: int, path: Path) -> bool:
    """Lock ``fd`` (True), or False when ``path`` is no longer the file locked; LockError if held elsewhere."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _read_soon(fd)
        raise LockError(_held_message(path, holder), holder=holder) from None
    except OSError as exc:  # ENOLCK, EOPNOTSUPP: a file system without locks
        raise LockError(
            f"cannot lock {path}: {os.strerror(exc.errno or errno.ENOLCK)}; the file system does not support "
            "locks (NFS mounted with nolock?): write the dataset to a local folder"
        ) from exc
    return _same_file(fd, path)


def _take_over(fd: int, path: Path) -> list[str]:
    """Write this process into the locked file; a note when it named an earlier holder (gone: we hold the lock)."""
    before = _read(fd)
    data = (json.dumps(holder_info(), sort_keys=True) + "\n").encode()
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        os.fsync(fd)
    except OSError as exc:
        raise storage_error(path, exc) from exc
    if not before:
        return []
    where = "" if before.get("host") == socket.gethostname() else f" on host {before.get('host', '?')}"
    return [
        f"took over {path}: it was left by pid {before.get('pid', '?')}{where} (started {before.get('started', '?')}),"
        " which no longer holds it (it ended without closing the dataset)"
    ]


def _held_message(path: Path, holder: dict) -> str:
    folder = path.parent
    if not holder:
        return f"dataset {folder} is being written by another process (its lock file {path} names none yet)"
    who = f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')}, since {holder.get('started', '?')}"
    text = f"dataset {folder} is being written by another process ({who}: {holder.get('command', '?')})"
    if holder.get("host") != socket.gethostname():
        return (
            f"{text}. That host is another machine sharing this folder: wait for its run to end; if no run is going "
            f"on there, delete {path}"
        )
    if holder.get("pid") == os.getpid():
        return f"{text}. This process already has it open: close that DatasetWriter first"
    return f"{text}. Wait for it to end, or write to another folder"


def _read(fd: int) -> dict:
    """The holder named in the lock file open as ``fd`` ({} when empty or unreadable)."""
    try:
        data = json.loads(os.pread(fd, 4096, 0) or b"{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _read_soon(fd: int) -> dict:
    """The holder named in the lock file, waiting up to HOLDER_WAIT_S for a holder that has just taken the lock to
    write its name ({} if it has not by then)."""
    deadline = time.monotonic() + HOLDER_WAIT_S
    while not (holder := _read(fd)) and time.monotonic() < deadline:
        time.sleep(0.005)
    return holder


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` is still the file open as ``fd``."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)
