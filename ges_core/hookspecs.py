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
    """Register grasp-execution experts.

    :param register: call ``register(ExpertSpec(name=..., entry_point="pkg.mod:factory", settings={...}))``
        once per expert. :meth:`ges_core.registry.Registry.build_expert` calls the factory as
        ``factory(context: ExpertContext, **settings) -> Expert``: ``context`` is a
        :class:`ges_core.policy.ExpertContext` (observation and action layouts, the hand, ``num_envs``, the
        simulator's name, the registry); ``settings`` are the spec's ``settings`` (the plugin's defaults, one
        source: ``ges info expert NAME`` lists them), then registry.yaml ``settings.expert.<name>``, then the
        caller's (``ges eval-experts --expert NAME:key=value``), key by key. An expert made for one hand and
        layout (a trained checkpoint) sets :attr:`ges_core.policy.Expert.made_for`; the registry then calls
        :func:`ges_core.policy.check_expert_fits`, which refuses a context that differs, naming both.
    """


@hookspec
def ges_register_gates(register: Callable[[GateSpec], None]) -> None:
    """Register expert-selection gates (factory returns a :class:`ges_core.policy.Gate`)."""
