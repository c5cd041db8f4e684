"""Torch -> numpy at the edges of the environment's per-step numpy code."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["as_numpy"]


def as_numpy(x, dtype: type | None = None) -> np.ndarray:
    """A torch tensor (any device, grad or not) or an array-like as numpy of ``dtype`` (None: its own).

    No copy where none is needed: a CPU tensor's array shares its memory.
    """
    if isinstance(x, torch.Tensor):
        try:
            x = x.numpy()
        except (RuntimeError, TypeError):  # requires grad, or not on the CPU
            x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)
