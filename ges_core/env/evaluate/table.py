"""The summary of an evaluation: one :class:`SplitRow` per split and ``all``, as a markdown table."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from ges_core.env.success import EndReason
from ges_core.objects.splits import SPLITS

__all__ = ["REASONS", "SplitRow", "format_table", "summarize"]

REASONS: tuple[str, ...] = tuple(r.name.lower() for r in EndReason if r is not EndReason.RUNNING) + ("error",)
"""End-reason columns of the table: the env's EndReason names, then 'error' (the object could not be set up)."""


@dataclass
class SplitRow:
    """One line of the summary table."""

    split: str
    objects: int = 0
    """Objects evaluated."""
    considered: int = 0
    """Objects of the hand in the dataset (before the selection rule)."""
    episodes: int = 0
    paper: int = 0
    """Episodes that met the paper's protocol."""
    peers: int = 0
    """Episodes that met the peers' protocol."""
    reasons: Counter = field(default_factory=Counter)

    @property
    def paper_rate(self) -> float | None:
        """Paper-protocol success rate over episodes (None without episodes)."""
        return self.paper / self.episodes if self.episodes else None

    @property
    def peers_rate(self) -> float | None:
        """Peers-protocol success rate over episodes (None without episodes)."""
        return self.peers / self.episodes if self.episodes else None

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {
            "split": self.split, "objects": self.objects, "considered": self.considered, "episodes": self.episodes,
            "paper_success": self.paper, "peers_success": self.peers, "paper_rate": self.paper_rate,
            "peers_rate": self.peers_rate, "end_reasons": {r: self.reasons.get(r, 0) for r in REASONS},
        }  # fmt: skip


def summarize(results: list[dict], considered: dict[str, int], splits: tuple[str, ...] = SPLITS) -> list[SplitRow]:
    """One row per split in ``splits`` and an ``all`` row; considered: split -> objects in the dataset."""
    rows = {s: SplitRow(s, considered=considered.get(s, 0)) for s in splits}
    total = SplitRow("all", considered=sum(considered.get(s, 0) for s in splits))
    for res in results:
        if res["split"] not in rows:
            continue
        for row in (rows[res["split"]], total):
            row.objects += 1
            row.episodes += res["envs"]
            row.paper += res["paper_success"]
            row.peers += res["peers_success"]
            row.reasons.update(res["end_reasons"])
    return [*rows.values(), total]


def format_table(rows: list[SplitRow], header: str = "") -> str:
    """Markdown table of ``rows`` under an optional header line."""
    reasons = [r for r in REASONS if any(row.reasons.get(r) for row in rows)] or ["success"]
    lines = [header, ""] if header else []
    lines.append("| split | objects | episodes | success (paper) | success (peers) | " + " | ".join(reasons) + " |")
    lines.append("|---" * (5 + len(reasons)) + "|")
    for row in rows:
        cells = [row.split, f"{row.objects}/{row.considered}", str(row.episodes)]
        cells += [_rate(row.paper, row.episodes), _rate(row.peers, row.episodes)]
        cells += [str(row.reasons.get(r, 0)) for r in reasons]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _rate(k: int, n: int) -> str:
    return f"{100 * k / n:.1f} % ({k}/{n})" if n else "-"
