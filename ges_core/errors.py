"""The one error hierarchy of GES-UniGrasp.

Every message says who failed, what went wrong and how to fix it. The CLI prints
``str(error)`` on one line and exits non-zero; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

__all__ = [
    "ArrayError",
    "AssetError",
    "BackendUnavailable",
    "ConfigError",
    "GesError",
    "LockError",
    "PluginError",
    "RegistrationError",
    "SimulationError",
    "StorageError",
    "SynthesisError",
    "UnknownNameError",
    "naming_plugin",
]


class GesError(Exception):
    """Base class of every error GES-UniGrasp raises on purpose."""


class PluginError(GesError):
    """A plugin failed to import or to register."""

    def __init__(self, message: str, *, plugin: str | None = None) -> None:
        super().__init__(message)
        self.plugin = plugin


@contextmanager
def naming_plugin(
    plugin: str, failed: str, fix: str, *, keep: tuple[type[Exception], ...] = (PluginError,)
) -> Iterator[None]:
    """Turn any exception raised inside the block into one PluginError naming ``plugin``.

    The message reads ``"{failed}: {Type}: {message}. {fix}"``; the original is chained (``--debug`` shows its
    traceback). Exceptions of the types in ``keep`` pass unchanged (they already say who failed).
    """
    try:
        yield
    except keep:
        raise
    except Exception as exc:  # noqa: BLE001 - a plugin may raise anything; we name it
        raise PluginError(f"{failed}: {type(exc).__name__}: {exc}. {fix}", plugin=plugin) from exc


class ConfigError(GesError):
    """A configuration value is missing, unknown or out of range."""

    def __init__(self, message: str, *, problems: list[str] | None = None) -> None:
        super().__init__(message)
        self.problems = problems or []


class RegistrationError(GesError):
    """Two plugins claim one name, or a spec is malformed."""


class UnknownNameError(GesError, KeyError):
    """A name was looked up that no plugin registered."""

    def __init__(self, kind: str, name: str, known: Iterable[str], *, where: str = "") -> None:
        known = sorted(known)
        close = difflib.get_close_matches(name, known, n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        listing = ", ".join(known) if known else "(none registered)"
        msg = f"unknown {kind} '{name}'{where}.{hint} Known {kind}s: {listing}."
        super().__init__(msg)
        self.kind, self.name, self.known = kind, name, known

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return str(self.args[0])


class ArrayError(GesError, ValueError):
    """An array argument has the wrong shape, is not numeric, or holds NaN, inf or a zero quaternion.

    One type for that one kind of mistake, wherever an array crosses a boundary (a simulator command, an
    environment action, a contact set, a point cloud); raised by :mod:`ges_core.arrays`. A ``ValueError``
    too, so ``except ValueError`` keeps working.
    """


class AssetError(GesError):
    """A hand or object asset is missing, unreadable or physically invalid."""


class BackendUnavailable(GesError):
    """A simulator or optional package is not installed or cannot start here."""


class SimulationError(GesError):
    """The simulator produced non-finite or exploding state (or a backend rejected a command).

    ``env_ids``: the envs whose state blew up, ascending; the message names each as ``env N``.
    Empty when the error concerns no env in particular (a bad command, a closed backend) or the
    backend cannot tell which: treat that as every env.
    """

    def __init__(self, message: str, *, env_ids: Iterable[int] = ()) -> None:
        super().__init__(message)
        self.env_ids: tuple[int, ...] = tuple(sorted({int(e) for e in env_ids}))


class SynthesisError(GesError):
    """Grasp synthesis cannot handle this object (no graspable width, degenerate point cloud, ...).

    Pipelines record it as that object's failure reason and go on with the next object.
    """

    def __init__(self, message: str, *, reason: str = "failed") -> None:
        super().__init__(message)
        self.reason = reason
        """Short machine-readable failure code, e.g. ``no_graspable_width`` or ``degenerate_cloud``."""


class StorageError(GesError, OSError):
    """A file or folder cannot be written: no space left, a quota, no permission, a read-only file system.

    Raised where GES-UniGrasp writes (:mod:`ges_core.paths`), with a message naming the path, the cause and what
    to do. Also an ``OSError`` (``errno`` and ``filename`` kept), so ``except OSError`` keeps working.
    """

    def __init__(self, message: str, *, path: str | None = None, errno: int | None = None) -> None:
        super().__init__(message)
        self.filename, self.errno = path, errno

    def __str__(self) -> str:  # OSError would otherwise format errno and filename itself
        return str(self.args[0])

    def __reduce__(self):  # keep errno and the path through pickling (a worker process raises it)
        return (type(self), self.args, {"filename": self.filename, "errno": self.errno})


class LockError(GesError):
    """Another process holds the lock of a folder this one wants to write (e.g. a dataset being written).

    ``holder``: what the lock file says about its holder (pid, host, started, command), {} when unreadable.
    """

    def __init__(self, message: str, *, holder: dict | None = None) -> None:
        super().__init__(message)
        self.holder = holder or {}
