"""The PPO expert: a policy trained by ``ges train-expert``, loaded from its checkpoint.

Light on purpose: the expert (torch, rsl-rl) lives in :mod:`ges_plugins.experts.ppo.expert`, loaded only when
the registry builds it (``registry.build_expert("ppo", context, checkpoint="runs/.../checkpoints/last.pt")``).
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import ExpertSpec


@hookimpl
def ges_register_experts(register: Callable[[ExpertSpec], None]) -> None:
    """Register the PPO checkpoint expert as ``ppo``."""
    register(
        ExpertSpec(
            name="ppo",
            entry_point="ges_plugins.experts.ppo.expert:build_expert",
            description="a PPO policy trained by 'ges train-expert' (setting checkpoint=PATH to its .pt file)",
            settings={"checkpoint": None, "deterministic": True},
            made_for="ges_plugins.experts.ppo.scope:checkpoint_scope",
        )
    )
