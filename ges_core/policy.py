"""Stage 2 interfaces: experts act, gates choose among experts.

Both work on batched torch tensors so that one call serves many environments.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from ges_core.errors import ConfigError

__all__ = ["Expert", "Gate"]


class Expert(ABC):
    """A grasp-execution policy (scripted, or PPO-trained)."""

    name: str = ""
    """Registry name."""

    @abstractmethod
    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Actions for a batch of observations.

        obs: (num_envs, obs_dim) float32, the environment's documented observation layout.
        Returns (num_envs, num_actions) float32 in [-1, 1] (normalized joint targets).
        """

    def reset(self, env_ids: torch.Tensor | None = None) -> None:  # noqa: B027 - optional hook
        """Forget per-episode state for ``env_ids`` (all if None); stateless experts ignore it."""


class Gate(ABC):
    """Chooses one expert per object from its point cloud.

    A gate is trained for a fixed, ordered list of experts (:attr:`experts`, the columns of
    :meth:`predict`); its checkpoint names them, and using it with other experts is an error
    (:meth:`check_experts`). Training, data and checkpoint formats live in :mod:`ges_core.gating`.
    """

    name: str = ""
    """Registry name."""

    experts: tuple[str, ...] = ()
    """Names of the experts the gate chooses among, in the order of :meth:`predict`'s columns."""

    @abstractmethod
    def predict(self, points: torch.Tensor) -> torch.Tensor:
        """Expert probabilities.

        points: (n, N, 3) float32 object point clouds, object frame, metres.
        Returns (n, k) float32, rows sum to 1, k = number of experts.
        """

    @abstractmethod
    def fit(self, data: Any, **options: Any) -> Any:
        """Train on ``data`` (a :class:`ges_core.gating.GateData`: object clouds and per-expert success
        rates); sets :attr:`experts` to the data's experts and returns the training history."""

    @abstractmethod
    def save(self, path: str | Path) -> None:
        """Write a checkpoint that names :attr:`experts`."""

    @classmethod
    @abstractmethod
    def load(cls, path: str | Path) -> Gate:
        """The gate saved at ``path``, with the experts it was trained for."""

    def check_experts(self, experts: Sequence[str]) -> None:
        """ConfigError naming both lists unless ``experts`` are the ones this gate was trained for (same order)."""
        if tuple(experts) != tuple(self.experts):
            raise ConfigError(
                f"gate '{self.name}' was trained for experts {list(self.experts)} but is used with "
                f"{list(experts)}; retrain it (ges train-gate) on a success matrix of these experts, "
                f"or pass the experts it was trained for"
            )

    def select(self, points: torch.Tensor) -> torch.Tensor:
        """Index (n,) int64 of the expert with the highest predicted score."""
        return self.predict(points).argmax(dim=-1)
