"""An expert made for the other form of the observation's wrist rotation, acting in this environment.

``EnvConfig.wrist_rotation`` chooses how the ``wrist_pose`` block holds the wrist's rotation (docs/env.md): the
rotation matrix's first two columns (the default since 8 December 2026) or a rotation vector (every checkpoint
trained before). The two forms hold the same rotation, so an expert made for one reads the other once each
observation is recast (:meth:`~ges_core.env.layout.ObservationLayout.recast`): :class:`RecastWrist` does that in
front of it, and :func:`inner_context` gives the context such an expert (and a residual policy's base expert) is
built in. Nothing else may differ: a checkpoint for another hand, goal prior or wrist step is refused as before.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import torch

from ges_core.policy import Expert, ExpertContext, ExpertScope

if TYPE_CHECKING:
    from ges_core.env.layout import ObservationLayout

__all__ = ["RecastWrist", "inner_context"]


def inner_context(scope: ExpertScope, context: ExpertContext) -> ExpertContext:
    """``context`` with its observation layout in the wrist form ``scope`` was made for (``context`` itself when they
    agree, or when the scope's wrist block is no known form: the fit check then names the difference)."""
    form = scope.wrist_rotation
    if form is None or form == context.obs_layout.wrist_rotation:
        return context
    return replace(context, obs_layout=context.obs_layout.with_wrist_rotation(form))


class RecastWrist(Expert):
    """``inner`` (built in :func:`inner_context`), fed this environment's observations recast to its wrist form."""

    def __init__(self, inner: Expert, context: ExpertContext, inner_layout: ObservationLayout) -> None:
        self.inner, self.outer_layout, self.inner_layout = inner, context.obs_layout, inner_layout
        self.name = inner.name
        scope = inner.made_for
        self.made_for = None if scope is None else scope.with_wrist_rotation(context.obs_layout.wrist_rotation)

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """The inner expert's actions for observations (n, obs size) of this environment's layout."""
        return self.inner.act(self.outer_layout.recast(obs, self.inner_layout))

    def reset(self, env_ids: torch.Tensor | None = None) -> None:
        """The inner expert forgets ``env_ids``' episodes."""
        self.inner.reset(env_ids)
