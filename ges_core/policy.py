"""Stage 2 interfaces: experts act, gates choose among experts.

Both work on batched torch tensors so that one call serves many environments.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch

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
    """Chooses one expert per object from its point cloud."""

    name: str = ""
    """Registry name."""

    @abstractmethod
    def predict(self, points: torch.Tensor) -> torch.Tensor:
        """Expert probabilities.

        points: (n, N, 3) float32 object point clouds, object frame, metres.
        Returns (n, k) float32, rows sum to 1, k = number of experts.
        """

    def select(self, points: torch.Tensor) -> torch.Tensor:
        """Index (n,) int64 of the expert with the highest predicted score."""
        return self.predict(points).argmax(dim=-1)
