"""The lint result type."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LintProblem"]


@dataclass(frozen=True)
class LintProblem:
    """One finding: which check found it, what it is, how to fix it.

    ``note=True`` marks something the framework handles itself (a ``<mimic>`` tag that became a
    coupling, a mesh already converted) or that the hand works with as given (an implausible inertia):
    printed, but ``ges hand lint`` still exits 0 for it.
    """

    check: str
    what: str
    fix: str
    note: bool = False

    def __str__(self) -> str:
        label = "note: " if self.note else ""
        return f"[{self.check}] {label}{self.what} -- fix: {self.fix}"
