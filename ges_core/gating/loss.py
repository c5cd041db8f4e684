"""The paper's gate loss and accuracy."""

from __future__ import annotations

import numpy as np
import torch

from ges_core.gating.data import best_experts

__all__ = ["gate_accuracy", "kl_loss"]


def kl_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L_KL = (1/N) sum_i D_KL(P_i || P_hat_i), P_hat = softmax(logits).

    logits: (N, k) float; target: (N, k) rows summing to 1 (zeros allowed: 0 log 0 = 0). Returns a
    scalar tensor, nats.
    """
    log_q = torch.log_softmax(logits, dim=-1)
    log_p = torch.log(target.clamp_min(torch.finfo(target.dtype).tiny))
    per_object = torch.where(target > 0, target * (log_p - log_q), torch.zeros_like(target)).sum(dim=-1)
    return per_object.mean()


def gate_accuracy(probs: np.ndarray | torch.Tensor, rates: np.ndarray) -> float:
    """Fraction of objects whose highest-scored expert is one of their best (the paper's gate accuracy).

    probs: (N, k) the gate's scores; rates: (N, k) the experts' success rates on the same objects.
    NaN when N is 0.
    """
    probs = probs.detach().cpu().numpy() if isinstance(probs, torch.Tensor) else np.asarray(probs)
    if len(probs) == 0:
        return float("nan")
    chosen = probs.argmax(axis=1)
    return float(best_experts(rates)[np.arange(len(chosen)), chosen].mean())
