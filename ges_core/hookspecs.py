"""Every hook GES-UniGrasp calls, in one place.

Registration hooks are collectors (as in ``llm`` and ``tox``): the core passes a ``register``
callable and a plugin calls it once per thing it provides. The core calls them through pluggy's
hook caller, stores the specs, rejects duplicate names (naming both sources) and answers look-ups.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from ges_core.specs import ExpertSpec, GateSpec, HandSpec, SimSpec

__all__ = ["hookimpl", "hookspec"]

PROJECT = "ges"
"""pluggy project name; also the prefix of every hook."""

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


# -- registration ---------------------------------------------------------------------------
@hookspec
def ges_register_hands(register: Callable[[HandSpec], None]) -> None:
    """Register hand models.

    :param register: call ``register(HandSpec(name=..., entry_point="pkg.mod:factory"))`` once
        per hand; the factory takes the hand's settings as keyword arguments (the spec's
        ``settings``, then ``registry.yaml``'s) and returns a :class:`ges_core.hand.HandModel`.
    """


@hookspec
def ges_register_sims(register: Callable[[SimSpec], None]) -> None:
    """Register simulator backends.

    :param register: call ``register(SimSpec(...))``; the factory is called as
        ``factory(scene_config, **settings)`` and returns a :class:`ges_core.sim.SimBackend`.
    """


@hookspec
def ges_register_experts(register: Callable[[ExpertSpec], None]) -> None:
    """Register grasp-execution experts (factory returns a :class:`ges_core.policy.Expert`)."""


@hookspec
def ges_register_gates(register: Callable[[GateSpec], None]) -> None:
    """Register expert-selection gates (factory returns a :class:`ges_core.policy.Gate`)."""
