"""PyBullet, imported and connected without its C-level chatter.

PyBullet 3.2.7 prints ``pybullet build time: ...`` to **stderr** when the module is imported
(measured: the line is on fd 2, not fd 1) and ``argv[0]=`` to **stdout** for every client
``BulletClient`` connects, with C ``printf``: ``contextlib.redirect_stdout`` cannot catch either,
and a program whose output is a report or a pipe (``ges sim check``) gets them mixed in. Every
module of this plugin imports ``pybullet`` through here, so the first import is the quiet one, and
builds clients with :func:`connect_direct`.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager, suppress

__all__ = ["BulletClient", "connect_direct", "p", "silenced"]


@contextmanager
def silenced(*fds: int) -> Iterator[None]:
    """Point the process's file descriptors ``fds`` (1: stdout, 2: stderr) at ``os.devnull`` for the block.

    C output is silenced too, and C's stdio buffers are flushed before the descriptors are
    restored (a pipe is block-buffered, so the text would otherwise come out later, on the real
    stream). The whole process loses those descriptors meanwhile, other threads included; the
    blocks this is used for take milliseconds. A descriptor that cannot be duplicated (closed, or
    an embedding host without one) is left alone.
    """
    with ExitStack() as stack:
        for fd in fds:
            stack.enter_context(_silenced_fd(fd))
        yield


@contextmanager
def _silenced_fd(fd: int) -> Iterator[None]:
    stream = {1: sys.stdout, 2: sys.stderr}.get(fd)
    _flush(stream)  # Python's text written before the block goes out first ...
    try:
        saved = os.dup(fd)
    except OSError:
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        _flush(stream)  # ... and the block's, Python's and C's, goes to devnull
        _flush_c_stdio()
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)


def _flush(stream: object) -> None:
    """Flush a Python text stream if there is one that can be flushed (None under pythonw, closed ones fail)."""
    with suppress(OSError, ValueError, AttributeError):
        stream.flush()


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: write out every C stdio buffer while the silenced descriptors point at devnull."""
    with suppress(OSError, AttributeError):  # no C library to reach (not seen on Linux or macOS)
        ctypes.CDLL(None).fflush(None)


with silenced(1, 2):
    import pybullet as p
    from pybullet_utils.bullet_client import BulletClient


def connect_direct() -> BulletClient:
    """A new headless (``p.DIRECT``) client, without the ``argv[0]=`` line PyBullet prints."""
    with silenced(1):
        return BulletClient(connection_mode=p.DIRECT)
