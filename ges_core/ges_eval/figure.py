"""The expert-fusion figure (as the paper's): per split, which experts each gate picks and how each expert does there.

One PNG, one column per split (train, unseen objects, unseen categories):

* top: the expert-selection distribution, the share of the split's objects each gate sent to each expert, beside
  the oracle's (the share where each expert is an object's best; ties split evenly);
* bottom: per object (rows) the success rate of every expert alone (grey, 0 white to 1 mid-grey, from the
  matrix), each gate's pick marked in its cell (one marker per gate) with the rate GES reached on that object.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ges_core.experts.matrix import SuccessMatrix
from ges_core.gating.data import best_experts
from ges_core.ges_eval.table import GesRow
from ges_core.objects.splits import SPLITS
from ges_core.paths import atomic_write_bytes

__all__ = ["fusion_figure"]

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
"""One marker shape per gate (a gate beyond eight reuses them)."""


def fusion_figure(
    path: str | Path, matrix: SuccessMatrix, experts: tuple[str, ...], ges: list[GesRow], protocol: str = "paper"
) -> Path:
    """Draw the figure (module docs) of ``matrix`` (the run's objects), the GES ``experts`` and each gate's row into
    ``path`` (PNG, written atomically); returns the path."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = [matrix.column(e) for e in experts]
    rates = matrix.rates(protocol)[:, cols]
    n_max = max([int(matrix.rows(s).sum()) for s in SPLITS] + [1])
    ratios = [1.0, max(1.0, min(0.08 * n_max, 5.0))]  # the object rows grow with the objects, up to 5x the bars
    size = (4.2 * len(SPLITS), 3.0 + min(0.22 * n_max, 14))
    fig, axes = plt.subplots(2, len(SPLITS), figsize=size, gridspec_kw={"height_ratios": ratios}, squeeze=False)
    for k, split in enumerate(SPLITS):
        rows = np.flatnonzero(matrix.rows(split))
        _selection(axes[0, k], rates[rows], experts, [_local(g, cols)[rows] for g in ges], [g.label for g in ges])
        axes[0, k].set_title(f"{split} ({len(rows)} objects)")
        _success(axes[1, k], rates[rows], [matrix.object_ids[i] for i in rows], experts, ges, cols, rows, protocol)
    fig.suptitle(f"GES expert selection and per-expert success ({protocol} protocol); markers: each gate's pick")
    handles, names = axes[1, 0].get_legend_handles_labels()
    for ax in axes[1, 1:]:
        if not handles:
            handles, names = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, names, loc="lower center", ncol=len(handles), fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue(), fix="choose another --out")


def _local(g: GesRow, cols: list[int]) -> np.ndarray:
    """(n_objects,) the gate's pick as an index into ``cols`` (the GES experts)."""
    return np.array([cols.index(c) for c in g.picked], dtype=np.int64)


def _selection(ax, rates: np.ndarray, experts, picks: list[np.ndarray], labels: list[str]) -> None:
    """Grouped bars: per expert, the share of objects each gate picked it, and the oracle's share."""
    k = len(experts)
    groups = [*labels, "oracle"]
    width = 0.8 / len(groups)
    done = ~np.isnan(rates).any(axis=1)
    best = best_experts(rates[done]) if done.any() else np.zeros((0, k), dtype=bool)
    oracle = (best / best.sum(axis=1, keepdims=True)).sum(axis=0) / max(len(best), 1)
    for i, name in enumerate(groups):
        share = oracle if name == "oracle" else np.bincount(picks[i], minlength=k) / max(len(picks[i]), 1)
        x = np.arange(k) + (i - (len(groups) - 1) / 2) * width
        ax.bar(x, share, width, label=name, hatch="//" if name == "oracle" else None,
               color="0.8" if name == "oracle" else f"C{i}", edgecolor="0.3")  # fmt: skip
    ax.set_xticks(np.arange(k), experts, rotation=20, fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("share of objects picked")
    ax.legend(fontsize=7)


def _success(ax, rates, ids, experts, ges: list[GesRow], cols, rows, protocol: str) -> None:
    """Objects x experts success (colour) with each gate's pick marked and GES's rate on the object."""
    n = len(ids)
    if n == 0:
        ax.text(0.5, 0.5, "no objects", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return
    # grey, 1.0 at mid-grey (vmax 1.6): the gates' coloured markers stay visible on any rate
    ax.imshow(np.nan_to_num(rates, nan=0.0).reshape(n, len(experts)), cmap="Greys", vmin=0, vmax=1.6,
              aspect="auto", interpolation="nearest")  # fmt: skip
    offsets = np.linspace(-0.25, 0.25, len(ges)) if len(ges) > 1 else [0.0]
    for gi, g in enumerate(ges):
        pick = _local(g, cols)[rows]
        eps = g.episodes[rows]
        ges_rate = np.where(eps > 0, g.successes[protocol][rows] / np.maximum(eps, 1), np.nan)
        ax.scatter(pick + offsets[gi], np.arange(n), marker=_MARKERS[gi % len(_MARKERS)], s=28,
                   facecolors="white", edgecolors=f"C{gi}", linewidths=1.6, label=f"{g.label} pick")  # fmt: skip
        for y, r in enumerate(ges_rate):
            text = "-" if np.isnan(r) else f"{r:.2f}"
            ax.text(len(experts) - 0.45 + 0.5 * gi, y, text, fontsize=6, va="center", color=f"C{gi}")
    ax.set_xlim(-0.5, len(experts) - 0.45 + 0.5 * len(ges))
    ax.set_xticks(np.arange(len(experts)), experts, rotation=20, fontsize=8)
    ax.set_yticks(np.arange(n), ids if n <= 40 else [""] * n, fontsize=6)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_xlabel("grey: expert alone (white 0, darker higher); right: GES", fontsize=8)
