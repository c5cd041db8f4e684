"""The lint result type."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LintProblem"]


@dataclass(frozen=True)
class LintProblem:
    """One problem: which check found it, what is wrong, how to fix it."""

    check: str
    what: str
    fix: str

    def __str__(self) -> str:
        return f"[{self.check}] {self.what} -- fix: {self.fix}"
