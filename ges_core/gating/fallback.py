"""A gate's pick with a fallback: the best single training expert unless the gate clearly prefers another.

The paper picks the expert of the highest predicted probability (the argmax). Where the experts differ on an object by
an episode or two, a gate trained on a few dozen objects learns that noise and sends objects to a weaker expert: on the
real scans and the ``tiny`` preset most gates so trained lost 3.5-10 points against the best single expert
(docs/evaluate.md). :class:`PickRule` keeps the argmax only where it beats a *fallback* expert, the one with the highest
mean success over the gate's training objects, by more than a probability ``margin``::

    pick(p) = argmax_j p_j   if max_j p_j - p_fallback > margin,   else fallback

``margin`` 0 is the argmax (up to exact ties with the fallback); a margin of 1 or more always picks the fallback.
:func:`fit_pick_rule` chooses the margin on the gate's held-out validation objects (never trained on): the margin
whose picks there have the highest mean success, the largest of equals (the fallback where the gate gains nothing).
``ges train-gate`` fits it after training and stores it in the checkpoint (:func:`~ges_core.gating.checkpoint.
write_pick_rule`); ``ges evaluate`` applies it (``--gate-argmax`` for the paper's rule).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ges_core.errors import ConfigError

__all__ = ["ARGMAX", "PickRule", "fit_pick_rule"]


@dataclass(frozen=True)
class PickRule:
    """How a gate's distribution becomes one expert (module docs). ``fallback`` None: the paper's argmax."""

    fallback: str | None = None
    """Label of the fallback expert (one of the gate's experts), None for the argmax."""
    margin: float = 0.0
    """Probability the gate's top expert must lead the fallback by, [0, 1]; above 1 is the same as 1."""
    how: str = "the paper's argmax"
    """How the rule was chosen, one line (shown by ``ges train-gate`` and stored with GES results)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise ConfigError(f"pick rule: margin must be a finite number >= 0, got {self.margin}")

    def choose(self, probs: torch.Tensor | np.ndarray, experts: Sequence[str]) -> np.ndarray:
        """(n,) int64 column index per row of ``probs`` ((n, k) scores over ``experts``, the gate's columns)."""
        p = _as_array(probs)
        if p.ndim != 2 or p.shape[1] != len(experts):
            raise ConfigError(f"pick rule: scores of shape {p.shape} for {len(experts)} experts")
        top = p.argmax(axis=1)
        if self.fallback is None:
            return top
        f = self.column(experts)
        gap = p[np.arange(len(p)), top] - p[:, f]
        return np.where(gap > self.margin, top, f)

    def column(self, experts: Sequence[str]) -> int:
        """Index of :attr:`fallback` in ``experts``; ConfigError naming both when it is not there."""
        if self.fallback not in experts:
            raise ConfigError(f"pick rule: fallback expert '{self.fallback}' is not one of the gate's {list(experts)}")
        return list(experts).index(self.fallback)

    def to_json(self) -> dict:
        return {"fallback": self.fallback, "margin": float(self.margin), "how": self.how}

    @classmethod
    def from_json(cls, data: dict | None) -> PickRule:
        """The rule stored by :meth:`to_json`; None or {} (a checkpoint written before rules): the argmax."""
        if not data:
            return ARGMAX
        return cls(data.get("fallback"), float(data.get("margin", 0.0)), str(data.get("how", "")))

    def describe(self) -> str:
        if self.fallback is None:
            return "argmax"
        if self.margin >= 1.0:
            return f"always {self.fallback} (the gate never led it by enough on validation)"
        return f"argmax if it leads {self.fallback} by more than {self.margin:.3g}, else {self.fallback}"


ARGMAX = PickRule()
"""The paper's rule."""


def fit_pick_rule(
    experts: Sequence[str],
    train_rates: np.ndarray,
    val_probs: torch.Tensor | np.ndarray,
    val_rates: np.ndarray,
) -> PickRule:
    """The :class:`PickRule` of a trained gate (module docs).

    experts: (k,) the gate's columns; train_rates: (n_train, k) success rates of the objects it was fitted on (the
    fallback: the column of the highest mean, the first of equals); val_probs: (n_val, k) its scores on the held-out
    objects and val_rates: (n_val, k) their rates. Without validation objects there is nothing to choose the margin
    on: the fallback with margin 0, which picks as the argmax does."""
    train_rates = np.asarray(train_rates, dtype=np.float64)
    val_rates = np.asarray(val_rates, dtype=np.float64)
    k = len(experts)
    if train_rates.ndim != 2 or train_rates.shape[1] != k or len(train_rates) == 0:
        raise ConfigError(f"pick rule: training rates of shape {train_rates.shape} for {k} experts (need 1+ objects)")
    means = train_rates.mean(axis=0)
    fallback = int(np.argmax(means))
    name = experts[fallback]
    best = f"{name} (mean {100 * means[fallback]:.1f} % over {len(train_rates)} training object(s))"
    if len(val_rates) == 0:
        return PickRule(name, 0.0, f"fallback {best}; no validation objects to choose a margin on: margin 0 (argmax)")
    p = _as_array(val_probs)
    if p.shape != val_rates.shape:
        raise ConfigError(f"pick rule: validation scores {p.shape} and rates {val_rates.shape} differ in shape")
    rows = np.arange(len(p))
    gap = p.max(axis=1) - p[:, fallback]
    candidates = np.unique(np.concatenate([[0.0], gap[gap > 0]]))  # a margin between two gaps picks as the lower
    scores = np.asarray(
        [round(float(val_rates[rows, PickRule(name, float(m)).choose(p, experts)].mean()), 9) for m in candidates]
    )
    chosen = int(np.flatnonzero(scores == scores.max())[-1])  # the largest margin of the best
    margin = float(candidates[chosen])
    if (chosen == len(candidates) - 1 and len(candidates) > 1) or not (gap > 0).any():
        margin = 1.0  # no validation object was worth leaving the fallback for: never leave it
    how = (
        f"fallback {best}; margin {margin:.3g} chosen on {len(p)} validation object(s): their mean success "
        f"{100 * scores[chosen]:.1f} % against {100 * scores[0]:.1f} % with the argmax and "
        f"{100 * float(val_rates[:, fallback].mean()):.1f} % with the fallback alone"
    )
    return PickRule(name, margin, how)


def _as_array(probs: torch.Tensor | np.ndarray) -> np.ndarray:
    """Scores as a float64 numpy array (a tensor detached and moved to the CPU)."""
    return probs.detach().cpu().double().numpy() if isinstance(probs, torch.Tensor) else np.asarray(probs, float)
