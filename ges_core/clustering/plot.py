"""The clusters picture: every object in the first two principal components, coloured by cluster."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ges_core.clustering.store import Clusters
from ges_core.paths import atomic_write_bytes

__all__ = ["plot_clusters"]

MARKERS = {"train": "o", "unseen_object": "^", "unseen_category": "s"}
"""Marker per split (filled: training objects define the clusters; the others are assigned to them)."""


def plot_clusters(clusters: Clusters, path: str | Path) -> Path:
    """Draw ``clusters`` (PCA of the standardized features, :attr:`Clusters.pca`) to the PNG ``path``, atomically.

    matplotlib's object interface with the Agg canvas: no pyplot global state, no display needed.
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 5.5), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    project = _projection(clusters)
    colours = [f"C{c % 10}" for c in range(clusters.k)]
    for split, marker in MARKERS.items():
        members = [m for m in clusters.objects.values() if m.split == split]
        if not members:
            continue
        xy = project(np.stack([m.features for m in members]))
        filled = split == "train"
        col = [colours[m.cluster] for m in members]
        ax.scatter(xy[:, 0], xy[:, 1], marker=marker, s=28, c=col if filled else "none",
                   edgecolors=col, linewidths=1.0)  # fmt: skip
        ax.scatter([], [], marker=marker, c="grey" if filled else "none", edgecolors="grey", label=_label(split))
    centres = (clusters.centres - np.asarray(clusters.pca["mean"])) @ np.asarray(clusters.pca["components"]).T
    ax.scatter(centres[:, 0], centres[:, 1], marker="X", s=160, c=colours, edgecolors="black")
    ax.scatter([], [], marker="X", s=100, c="grey", edgecolors="black", label="centres (colour: cluster)")
    for c, (x, y) in enumerate(centres):
        ax.annotate(f"{c}", (x, y), xytext=(6, 6), textcoords="offset points", fontsize=11, weight="bold")
    ratio = clusters.pca.get("explained_variance_ratio", [0.0, 0.0])
    ax.set_xlabel(f"PC 1 ({100 * ratio[0]:.0f} % of the variance)")
    ax.set_ylabel(f"PC 2 ({100 * ratio[1]:.0f} % of the variance)")
    sizes = ", ".join(str(n) for n in clusters.sizes(split="train"))
    ax.set_title(f"{len(clusters.objects)} objects, k = {clusters.k} (training objects per cluster: {sizes})")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return atomic_write_bytes(path, buffer.getvalue())


def _label(split: str) -> str:
    return {"train": "train (defines the clusters)"}.get(split, split.replace("_", " "))


def _projection(clusters: Clusters):
    """Raw features (n, F) -> (n, 2) coordinates on the picture's principal axes."""
    mean, axes = np.asarray(clusters.pca["mean"]), np.asarray(clusters.pca["components"])
    return lambda features: (clusters.standardize(features) - mean) @ axes.T
