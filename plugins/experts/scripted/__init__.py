"""The scripted baseline expert: approach the grasp, close, pause, carry the object up (no learning).

Light on purpose: the expert (and torch) lives in :mod:`ges_plugins.experts.scripted.expert`, loaded only when
the registry builds it; the registered settings are :class:`~ges_plugins.experts.scripted.config.ScriptedConfig`'s
defaults (one source).
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import ExpertSpec
from ges_plugins.experts.scripted.config import ScriptedConfig


@hookimpl
def ges_register_experts(register: Callable[[ExpertSpec], None]) -> None:
    """Register the scripted baseline as ``scripted``."""
    register(
        ExpertSpec(
            name="scripted",
            entry_point="ges_plugins.experts.scripted.expert:build_expert",
            description="scripted baseline: approach the Stage 1 grasp, close with the hand's squeeze, carry up",
            settings=ScriptedConfig().model_dump(),
        )
    )
